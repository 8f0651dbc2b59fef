"""Every Python snippet of the documentation runs (docs/_scripts/snippets.py explains how the
snippets of a page are collected and run)."""

import importlib.util
import pathlib

import matplotlib
import pytest


matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


_SNIPPETS = pathlib.Path(__file__).resolve().parents[1] / "docs" / "_scripts" / "snippets.py"
_SPEC = importlib.util.spec_from_file_location("docs_snippets", _SNIPPETS)
snippets = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(snippets)


def test_extractor_finds_blocks_and_skip_marks(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "# t\n\n```python\nx = 1\n```\n\n<!-- snippet: skip -->\n```python\nraise SystemExit\n```\n"
        "\n```bash\nls\n```\n\n!!! note\n    ```python\n    y = x + 1\n    ```\n"
    )
    found = snippets.blocks(page)
    assert [(code, run) for _, code, run in found] == [
        ("x = 1\n", True),
        ("raise SystemExit\n", False),
        ("y = x + 1\n", True),
    ]
    assert snippets.run_page(page)["y"] == 2


def test_pages_with_snippets_are_found():
    names = {p.relative_to(snippets.DOCS).as_posix() for p in snippets.pages()}
    assert "getting-started.md" in names


@pytest.mark.parametrize(
    "page", snippets.pages(), ids=lambda p: p.relative_to(snippets.DOCS).as_posix()
)
def test_snippets_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    try:
        snippets.run_page(page)
    finally:
        plt.close("all")
