"""Every Python snippet of the documentation runs (docs/_scripts/snippets.py explains how the
snippets of a page are collected and run).

Speed: the time is XLA compilation and tracing, about 3-6 s per distinct compiled program on
two CPU cores (some thirty programs); running the snippets themselves takes seconds. So the
snippets are compiled with XLA's optimisations off (`quick_compiles`), and the pages run in
one process, where pages that solve the same model with the same static configuration share
its compiled program: the solve is cached by structure (tolerances, `args`, `y0` and the
interval are run-time values), and `jax.grad` without an outer `jax.jit` reuses the cached
derivative (concepts/gradients.md and tutorials/calibration.md share one). Keep snippets
small (short intervals, small batches), reuse a configuration another page already compiled
where the content allows, and avoid a new program per page.
"""

import importlib.util
import inspect
import pathlib
import re
import shlex
import subprocess
import sys

import jax
import matplotlib
import pytest

import nivpjax as nj
from nivpjax._batched import _batched_jit
from nivpjax._solve import _solve_jit


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def _script(name):
    path = pathlib.Path(__file__).resolve().parents[1] / "docs" / "_scripts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"docs_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


snippets = _script("snippets")
check_site = _script("check_site")

# The only snippets that are not run (marked `<!-- snippet: skip: why -->` in the page), and
# why. Every other snippet runs; a new skip must be added here, with its reason.
SKIPPED = {
    # `nj.fit` of three friction parameters from four starts through 12 s of stick-slip:
    # about a minute on two cores (run by hand, as is examples/calibrate_slider.py).
    "tutorials/calibration.md": 1,
    # `learn.train` (compiles one large vmapped program: minutes), a gymnasium episode
    # (compiles the environment's reset, step and reference solve) and the fault study's
    # environment (compiles its three solves; tests/test_learn_fault.py runs it).
    "tutorials/learned-step-size.md": 3,
    # rejax SAC on the gymnax environment: needs the optional `rl` extra.
    "api/rl.md": 1,
    # `jax.distributed.initialize` for a sweep across machines (two processes; the
    # localhost run is tests/test_batched.py::test_two_processes_equal_one).
    "tutorials/batched-sweeps.md": 1,
    # The study's dense fault kernel: a file that does not ship with the package.
    "tutorials/fault.md": 1,
}


def test_extractor_finds_blocks_and_skip_marks(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "# t\n\n```python\nx = 1\n```\n\n<!-- snippet: skip -->\n```python\nraise SystemExit\n```\n"
        "\n<!-- snippet: skip: too slow -->\n```python\nraise SystemExit\n```\n"
        "\n```bash\nls\n```\n\n!!! note\n    ```python\n    y = x + 1\n    ```\n"
    )
    found = snippets.blocks(page)
    assert [(code, run) for _, code, run in found] == [
        ("x = 1\n", True),
        ("raise SystemExit\n", False),
        ("raise SystemExit\n", False),
        ("y = x + 1\n", True),
    ]
    assert snippets.run_page(page)["y"] == 2


def test_pages_with_snippets_are_found():
    names = {p.relative_to(snippets.DOCS).as_posix() for p in snippets.pages()}
    assert "getting-started.md" in names


def test_skipped_snippets_are_the_listed_ones():
    skipped = {}
    for page in sorted(snippets.DOCS.rglob("*.md")):
        if "_scripts" in page.parts:
            continue
        count = sum(not run for *_, run in snippets.blocks(page))
        if count:
            skipped[page.relative_to(snippets.DOCS).as_posix()] = count
    assert skipped == SKIPPED


@pytest.fixture(scope="module")
def quick_compiles():
    """XLA's optimisation passes are off while the snippets run (`jax_disable_most_optimizations`):
    the snippets check that the code runs and what it computes, not how fast, and their
    programs then compile about a third faster (measured: 196 s -> 134 s of CPU for this
    file). Afterwards every solve program the snippets used (compiled, called with new
    argument types, or transformed with `grad`/`jacfwd`/`vmap`) is dropped from the compile
    cache, with the executables JAX derived from it, so a later test with the same structure
    compiles its own, optimised program. (`jax.clear_caches()` would do more than that: other
    tests that count compilations would then see extra ones.)"""
    caches = (_solve_jit, _batched_jit)
    used = [set() for _ in caches]
    for cache, keys in zip(caches, used):

        def program(key, nested=False, _lookup=cache._program, _keys=keys):
            _keys.add(key)
            return _lookup(key, nested)

        cache._program = program  # records every key the snippets look up
    previous = jax.config.read("jax_disable_most_optimizations")
    jax.config.update("jax_disable_most_optimizations", True)
    try:
        yield
    finally:
        jax.config.update("jax_disable_most_optimizations", previous)
        for cache, keys in zip(caches, used):
            del cache._program
            for key in keys:
                cache._programs.pop(key, None)
            cache._seen = {s for s in cache._seen if s[0] in cache._programs}


@pytest.mark.parametrize(
    "page", snippets.pages(), ids=lambda p: p.relative_to(snippets.DOCS).as_posix()
)
def test_snippets_run(page, tmp_path, monkeypatch, quick_compiles):
    monkeypatch.chdir(tmp_path)
    try:
        snippets.run_page(page)
    finally:
        plt.close("all")


def _scene_of(fn):
    try:
        out = fn()
    except TypeError:  # a helper with required arguments
        return False
    return isinstance(out, tuple) and isinstance(out[0], nj.Scene)


def test_readme_and_home_count_the_scenes():
    """The README and the docs home say how many classic systems `nivpjax.scenes` builds
    (the README said eight, the home nine): count the constructors that return a scene."""
    constructors = {
        name: fn
        for name, fn in inspect.getmembers(nj.scenes, inspect.isfunction)
        if not name.startswith("_") and fn.__module__ == nj.scenes.__name__
    }
    # The large systems are counted apart ("and three large ones"); helpers such as
    # `fault_units` return no scene, `load_fault_kernel` needs a path.
    large = {"fault", "spring_block_chain", "chain_of_balls"}
    built = [name for name, fn in constructors.items() if name not in large and _scene_of(fn)]
    words = "zero one two three four five six seven eight nine ten eleven twelve".split()
    said = f"{words[len(built)]} classic systems"
    root = snippets.DOCS.parent
    for page in (root / "README.md", snippets.DOCS / "index.md"):
        assert said in page.read_text(), f"{page.name} does not say {said!r} ({built})"


def test_readme_test_command_prints_the_summary_line(tmp_path):
    """The README's test command ends with pytest's summary line (`N passed in ...`), also
    with a `-q` of the user's: a `-q` in the project's addopts made that `-qq`, which prints
    dots only. Run on a one-test file with the project's configuration."""

    root = snippets.DOCS.parent
    readme = (root / "README.md").read_text()
    command = re.search(r"Run the tests.*?```bash\n(.*?)\n```", readme, re.S).group(1)
    args = shlex.split(command)
    assert args[:3] == ["python", "-m", "pytest"] and args[-1] == "tests", command
    (tmp_path / "test_one.py").write_text("def test_one():\n    pass\n")
    config = ["-c", str(root / "pyproject.toml"), "--rootdir", str(tmp_path)]
    config += ["-p", "no:cacheprovider"]
    # With a `-q` of the user's (without it pytest is more verbose still).
    run = [sys.executable, *args[1:-1], *config, "-q", str(tmp_path / "test_one.py")]
    out = subprocess.run(run, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    last = out.stdout.strip().splitlines()[-1]
    assert re.search(r"\b1 passed\b", last), (out.stdout, out.stderr)


def _headings(page):
    """The Markdown headings of a page, outside code blocks."""
    fenced, out = False, []
    for line in page.read_text().splitlines():
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        elif not fenced and re.match(r"#{1,6} ", line):
            out.append(line)
    return out


def test_headings_and_nav_titles_have_no_tex():
    """A heading with maths shows as raw TeX in the tables of contents (`The scaling
    \\(\\rho\\)`): headings and the nav of mkdocs.yml write symbols in Unicode instead."""
    root = snippets.DOCS.parent
    pages = [p for p in snippets.DOCS.rglob("*.md") if "_scripts" not in p.parts]
    pages += sorted((root / "benchmarks" / "results").glob("*.md"))
    bad = [(p.name, h) for p in pages for h in _headings(p) if check_site.RAW_TEX.search(h)]
    nav = (root / "mkdocs.yml").read_text().split("\nnav:", 1)[1]
    bad += [("mkdocs.yml", line) for line in nav.splitlines() if check_site.RAW_TEX.search(line)]
    assert not bad


def test_site_check_finds_raw_tex_in_titles(tmp_path):
    toc = '<a href="#s" class="md-nav__link"><span>The scaling \\(\\rho\\)</span></a>'
    (tmp_path / "bad.html").write_text(f"<title>Formulation</title><nav>{toc}</nav>")
    (tmp_path / "good.html").write_text(
        '<title>Formulation</title><a class="md-nav__link">The scaling ρ</a>'
        '<h2>The scaling <span class="arithmatex">\\(\\rho\\)</span></h2>'
    )
    problems = check_site.check_titles(tmp_path)
    assert len(problems) == 1 and problems[0].startswith("bad.html: raw TeX"), problems
