"""Check the built documentation site (after `mkdocs build --strict`) in a real browser.

1. Every internal link and anchor of every built page resolves, and every script,
   stylesheet, image and font the pages load is local (the site works offline: no CDN).
   No navigation, table-of-contents or page title shows raw TeX (a heading with maths).
2. Served on 127.0.0.1 and opened in headless Debian Chromium with every host other than
   127.0.0.1 unresolvable, the maths renders: after the page's JavaScript ran, every
   `arithmatex` element holds rendered KaTeX and none holds a KaTeX error. In a window
   1280 px wide, no displayed equation is wider than its box (which would clip it, or
   hide its end behind a scroll bar): a script the check's server adds to each page
   measures every one once KaTeX has rendered them.
3. The API pages document every public name of `nivpjax` and the public functions and
   classes of its public submodules and subpackages (`scenes`, `compat`, `learn`,
   `learn.tasks`, `learn.pretrained`, `rl`).
4. Screenshots of the main pages are written to the output folder (default
   `site-screenshots/`) for a human to look at.

Run from the repository root:  python docs/_scripts/check_site.py [--site site] [--out DIR]
Exits 1 and lists the problems if any check fails.
"""

import argparse
import functools
import html
import html.parser
import http.server
import importlib
import inspect
import json
import os
import pathlib
import posixpath
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import types
import urllib.parse


SCREENSHOTS = [
    "",
    "getting-started/",
    "concepts/formulation/",
    "concepts/projectors/",
    "concepts/integrators/",
    "tutorials/bouncing-ball/",
    "tutorials/relay/",
    "extending/",
    "api/projectors/",
    "api/solve/",
    "benchmarks/",
    "benchmarks/results/",
    "migration/",
]
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    # Nothing but the local server can be reached: maths that renders here renders offline.
    "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
]


class _Page(html.parser.HTMLParser):
    """Links, loaded assets and element ids of one HTML page."""

    def __init__(self):
        super().__init__()
        self.links, self.assets, self.ids = [], [], set()
        self.maths = 0
        self.titles = []  # texts of the navigation and table-of-contents links, the <title>
        self._title = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "title" or (tag == "a" and "md-nav__link" in (a.get("class") or "").split()):
            self._title = []
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "a" and a.get("href"):
            self.links.append(a["href"])
        if tag in ("script", "img", "iframe", "source") and a.get("src"):
            self.assets.append(a["src"])
        if tag == "link" and a.get("href") and a.get("rel") != "canonical":
            self.assets.append(a["href"])
        if "arithmatex" in (a.get("class") or "").split():
            self.maths += 1

    def handle_data(self, data):
        if self._title is not None:
            self._title.append(data)

    def handle_endtag(self, tag):
        if tag in ("a", "title") and self._title is not None:
            self.titles.append(" ".join("".join(self._title).split()))
            self._title = None


def _external(url):
    return bool(urllib.parse.urlsplit(url).scheme) or url.startswith("//")


def _target(site, page_rel, url):
    """The file a relative URL of page `page_rel` points to, and its fragment."""
    parts = urllib.parse.urlsplit(url)
    base = "" if parts.path.startswith("/") else posixpath.dirname(page_rel)
    path = urllib.parse.unquote(parts.path).lstrip("/")
    path = posixpath.normpath(posixpath.join(base, path))
    if not parts.path:
        path = page_rel
    full = site / path
    if full.is_dir():
        full = full / "index.html"
    return full, parts.fragment


@functools.cache
def _parse(path):
    page = _Page()
    page.feed(path.read_text(encoding="utf-8", errors="replace"))
    return page


def check_links(site):
    problems = []
    for path in sorted(site.rglob("*.html")):
        rel = path.relative_to(site).as_posix()
        page = _parse(path)
        for url in page.assets:
            if _external(url):
                problems.append(f"{rel}: loads an external asset {url}")
            elif not _target(site, rel, url)[0].exists():
                problems.append(f"{rel}: missing asset {url}")
        for url in page.links:
            if _external(url) or url.startswith(("mailto:", "javascript:")):
                continue
            target, fragment = _target(site, rel, url)
            if not target.exists():
                problems.append(f"{rel}: broken link {url}")
            elif fragment and target.suffix == ".html" and fragment not in _parse(target).ids:
                problems.append(f"{rel}: broken anchor {url}")
    for css in sorted(site.rglob("*.css")):
        for url in re.findall(r"url\(\s*['\"]?([^'\")]+)", css.read_text(errors="replace")):
            if _external(url) and not url.startswith("data:"):
                problems.append(f"{css.relative_to(site)}: loads an external asset {url}")
    return problems


# TeX that a navigation or table-of-contents title shows as typed: a heading with maths
# (`## The scaling $\rho$`) puts `\(\rho\)` there, where nothing renders it.
RAW_TEX = re.compile(r"\\[(\[]|\\[A-Za-z]+|\$")


def check_titles(site):
    """No raw TeX in the navigation, the tables of contents or the page titles."""
    problems = []
    for path in sorted(site.rglob("*.html")):
        rel = path.relative_to(site).as_posix()
        for title in sorted(set(_parse(path).titles)):
            if RAW_TEX.search(title):
                problems.append(f"{rel}: raw TeX in a navigation or TOC title: {title!r}")
    return problems


# Public subpackages that `import nivpjax` does not import itself (each needs its own
# optional dependencies: optax for `learn`, gymnasium for `rl`).
SUBPACKAGES = (
    "nivpjax.compat",
    "nivpjax.learn",
    "nivpjax.learn.tasks",
    "nivpjax.learn.pretrained",
    "nivpjax.rl",
)


def _module_names(path, module, seen):
    """`path.f` for the public functions and classes defined in `module`, and recursively in
    its public submodules."""
    out = set()
    seen.add(module.__name__)
    for sub, member in vars(module).items():
        if sub.startswith("_"):
            continue
        if isinstance(member, types.ModuleType):
            if member.__name__.startswith(module.__name__ + ".") and member.__name__ not in seen:
                out |= _module_names(f"{path}.{sub}", member, seen)
            continue
        defined_here = getattr(member, "__module__", "") or ""
        if defined_here.startswith(module.__name__) and (
            inspect.isclass(member) or callable(member)
        ):
            out.add(f"{path}.{sub}")
    return out


def public_names():
    """`nivpjax.X` for every public name, plus `nivpjax.mod.f` for the public functions and
    classes defined in each public submodule (`nivpjax.scenes`, `nivpjax.compat`,
    `nivpjax.learn` with `learn.tasks` and `learn.pretrained`, `nivpjax.rl`)."""
    sys.path.insert(0, os.getcwd())
    nivpjax = importlib.import_module("nivpjax")
    for name in SUBPACKAGES:
        importlib.import_module(name)
    names = set(getattr(nivpjax, "__all__", ()))
    names |= {n for n in vars(nivpjax) if not n.startswith("_")}
    out = set()
    for name in sorted(names):
        obj = getattr(nivpjax, name)
        if isinstance(obj, types.ModuleType):
            out |= _module_names(f"nivpjax.{name}", obj, {nivpjax.__name__})
        else:
            out.add(f"nivpjax.{name}")
    return out


def _resolve(name):
    # The object a dotted public name refers to.
    parts = name.split(".")
    obj = importlib.import_module(parts[0])
    for part in parts[1:]:
        obj = getattr(obj, part)
    return obj


def check_api(site):
    documented = set()
    for path in (site / "api").rglob("*.html"):
        documented |= _parse(path).ids
    # A re-exported object (`nivpjax.learn.FaultEnv` is `nivpjax.learn.fault.FaultEnv`)
    # is documented once, under either of its names.
    covered = {id(_resolve(name)) for name in documented & public_names()}
    missing = sorted(
        name for name in public_names() - documented if id(_resolve(name)) not in covered
    )
    return [f"API reference lacks {name}" for name in missing]


# Added by the check's server before `</body>` of each page: once KaTeX has rendered every
# formula, it lists the displayed equations wider than their box (`scrollWidth` beyond
# `clientWidth`: clipped, or scrolled at this width) in a body attribute `--dump-dom` shows.
MEASURE_MATHS = """<script>
(function () {
  function measure() {
    var maths = document.querySelectorAll(".arithmatex");
    for (var i = 0; i < maths.length; i++) {
      if (!maths[i].dataset.rendered) return setTimeout(measure, 50);
    }
    var clipped = [];
    document.querySelectorAll("div.arithmatex").forEach(function (el) {
      var over = el.scrollWidth - el.clientWidth;
      if (over > 1) {
        var tex = el.querySelector("annotation");
        var text = (tex ? tex.textContent : el.textContent).replace(/\\s+/g, " ").trim();
        clipped.push(over + " px too wide: " + text.slice(0, 70));
      }
    });
    document.body.setAttribute("data-clipped-maths", JSON.stringify(clipped));
  }
  window.addEventListener("load", function () { setTimeout(measure, 0); });
})();
</script>"""
MEASURE_WIDTH = 1280


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass

    def do_GET(self):
        path = pathlib.Path(self.translate_path(self.path))
        if path.is_dir():
            path = path / "index.html"
        if path.suffix != ".html" or not path.is_file():
            return super().do_GET()
        body = path.read_bytes().replace(b"</body>", MEASURE_MATHS.encode() + b"</body>", 1)
        self.send_response(200)
        self.send_header("Content-Type", "text/html; charset=utf-8")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


def clipped_maths(dom: str):
    """The measuring script's list of equations wider than their box, or None if it did
    not run."""
    found = re.search(r'data-clipped-maths="([^"]*)"', dom)
    return None if found is None else json.loads(html.unescape(found.group(1)))


def _serve(site):
    handler = functools.partial(_QuietHandler, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    raise SystemExit("check_site: no chromium on PATH (Debian: apt-get install chromium)")


def _browser(chromium, profile, *args):
    """Run Chromium; a run that hangs counts as an empty result (reported by the caller)."""
    cmd = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=90)
    except subprocess.TimeoutExpired:
        return subprocess.CompletedProcess(cmd, 124, "", "chromium timed out after 90 s")


def check_browser(site, out):
    chromium = _chromium()
    server = _serve(site)
    root = f"http://127.0.0.1:{server.server_address[1]}/"
    problems, rendered = [], 0
    out.mkdir(parents=True, exist_ok=True)
    try:
        with tempfile.TemporaryDirectory() as profile:
            for path in sorted(site.rglob("*.html")):
                rel = path.relative_to(site).as_posix()
                if not _parse(path).maths:
                    continue
                url = root + rel.removesuffix("index.html")
                dom = _browser(
                    chromium,
                    profile,
                    f"--window-size={MEASURE_WIDTH},1400",
                    "--virtual-time-budget=10000",
                    "--dump-dom",
                    url,
                )
                maths = len(re.findall(r'class="arithmatex', dom.stdout))
                done = len(re.findall(r'data-rendered="1"', dom.stdout))
                katex = len(re.findall(r'class="katex"', dom.stdout))
                errors = len(re.findall(r"katex-error", dom.stdout))
                if not maths or done < maths or katex < maths or errors:
                    problems.append(
                        f"{rel}: maths not rendered ({maths} formulas, {done} rendered, "
                        f"{katex} KaTeX nodes, {errors} KaTeX errors)"
                    )
                rendered += done
                clipped = clipped_maths(dom.stdout)
                if clipped is None:
                    problems.append(f"{rel}: the equation widths were not measured")
                for item in clipped or ():
                    problems.append(f"{rel}: at {MEASURE_WIDTH} px an equation is {item}")
            for page in SCREENSHOTS:
                name = (page.strip("/").replace("/", "-") or "index") + ".png"
                shot = _browser(
                    chromium,
                    profile,
                    "--window-size=1280,1400",
                    "--virtual-time-budget=10000",
                    f"--screenshot={out / name}",
                    root + page,
                )
                if not (out / name).exists():
                    problems.append(f"{page}: no screenshot ({shot.stderr.strip()[-300:]})")
    finally:
        server.shutdown()
    print(f"check_site: {rendered} formulas rendered by KaTeX; screenshots in {out}")
    return problems


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--site", default="site", type=pathlib.Path)
    parser.add_argument("--out", default="site-screenshots", type=pathlib.Path)
    parser.add_argument("--no-browser", action="store_true", help="static checks only")
    opts = parser.parse_args()
    site = opts.site.resolve()
    if not (site / "index.html").exists():
        raise SystemExit(f"check_site: {site}/index.html not found; run `mkdocs build` first")
    problems = check_links(site) + check_titles(site) + check_api(site)
    if not opts.no_browser:
        problems += check_browser(site, opts.out.resolve())
    for p in problems:
        print("check_site:", p)
    pages = len(list(site.rglob("*.html")))
    print(f"check_site: {pages} pages, {len(problems)} problems")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
