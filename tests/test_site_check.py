"""The site check's clipped-equation test (docs/_scripts/check_site.py): in a real
Chromium, a displayed equation wider than its box is reported, one that fits is not."""

import importlib.util
import pathlib
import shutil
import tempfile

import pytest


def _check_site():
    path = pathlib.Path(__file__).resolve().parents[1] / "docs" / "_scripts" / "check_site.py"
    spec = importlib.util.spec_from_file_location("docs_check_site_clip", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


check_site = _check_site()


def test_clipped_maths_reads_the_measurement():
    dom = '<body data-clipped-maths="[&quot;612 px too wide: x = 1&quot;]"><p></p></body>'
    assert check_site.clipped_maths(dom) == ["612 px too wide: x = 1"]
    assert check_site.clipped_maths("<body></body>") is None  # the script did not run


@pytest.mark.skipif(not shutil.which("chromium"), reason="needs Debian's chromium")
def test_browser_reports_an_equation_wider_than_its_box(tmp_path):
    box = 'class="arithmatex" data-rendered="1" style="width: 300px; overflow-x: auto"'
    page = (
        "<html><body><article class='md-typeset'>"
        f'<div {box}><span style="display: inline-block; width: 900px">wide</span></div>'
        f'<div {box}><span style="display: inline-block; width: 200px">narrow</span></div>'
        "</article></body></html>"
    )
    (tmp_path / "index.html").write_text(page)
    server = check_site._serve(tmp_path)
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/"
        with tempfile.TemporaryDirectory() as profile:
            dom = check_site._browser(
                check_site._chromium(),
                profile,
                f"--window-size={check_site.MEASURE_WIDTH},800",
                "--virtual-time-budget=5000",
                "--dump-dom",
                url,
            )
    finally:
        server.shutdown()
    clipped = check_site.clipped_maths(dom.stdout)
    assert clipped is not None and len(clipped) == 1, (clipped, dom.stderr[-500:])
    assert clipped[0].startswith("600 px too wide: wide"), clipped
