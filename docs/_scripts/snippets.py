"""Extract and run the Python snippets of the documentation.

Every fenced block opened with three backticks and `python` in a page under docs/ is a
snippet. The snippets of one page run in order in one shared namespace, as a reader would
type them. A block preceded by the line `<!-- snippet: skip: why -->` (or the bare
`<!-- snippet: skip -->`) is not run: use it only for code too slow or too invasive for CI
(a training run, a long fit), say why in the marker, and list the page in
`tests/test_docs.py`'s `SKIPPED`.
"""

import pathlib
import re


DOCS = pathlib.Path(__file__).resolve().parents[1]
SKIP_MARK = re.compile(r"^<!--\s*snippet:\s*skip(?::.*?)?\s*-->$")
_FENCE = re.compile(r"^(?P<indent>[ ]*)(?P<fence>`{3,}|~{3,})\s*(?P<lang>[\w+-]*)")


def blocks(path):
    """`(line, code, run)` for each fenced Python block of the page at `path`."""
    lines = pathlib.Path(path).read_text(encoding="utf-8").splitlines()
    out, i = [], 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, lang = len(m["indent"]), m["fence"], m["lang"]
        start, body = i + 1, []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            body.append(lines[i][indent:])
            i += 1
        i += 1
        if lang in ("python", "py"):
            previous = next((ln.strip() for ln in reversed(lines[: start - 1]) if ln.strip()), "")
            out.append((start + 1, "\n".join(body) + "\n", not SKIP_MARK.match(previous)))
    return out


def pages():
    """Every Markdown page under docs/ that has at least one snippet to run."""
    return sorted(
        p for p in DOCS.rglob("*.md") if "_scripts" not in p.parts and any(r for *_, r in blocks(p))
    )


def run_page(path):
    """Run the page's snippets in order in one namespace and return the namespace."""
    namespace = {"__name__": "__docs__"}
    for line, code, run in blocks(path):
        if run:
            exec(compile(code, f"{path}:{line}", "exec"), namespace)
    return namespace
