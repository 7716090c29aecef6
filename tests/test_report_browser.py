"""The report page in a real browser: Debian's chromium, headless, opens a tiny
report built by the code (never the committed one) from the file system and
must show a non-blank page, log nothing to the console, draw the 3-D viewer's
canvas and find every picture it links.  Skipped, with the reason, where no
chromium is installed (CI installs it: see .ci/run)."""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from test_report import tiny_report  # noqa: F401 - the fixture builds the tiny report

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install chromium); "
                             "the page is not opened in a browser here")
# software WebGL (SwiftShader) in a headless browser with no GPU or display
FLAGS = ["--headless", "--no-sandbox", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
         "--window-size=1400,1800", "--virtual-time-budget=8000", "--hide-scrollbars"]


def _chromium(*args, timeout=120):
    return subprocess.run([CHROMIUM, *FLAGS, *args], capture_output=True, text=True,
                          timeout=timeout)


def _console(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ":CONSOLE" in ln]


def _page(path: Path):
    dom = _chromium("--enable-logging=stderr", "--v=0", "--dump-dom", path.as_uri())
    assert dom.returncode == 0, dom.stderr[-2000:]
    return dom.stdout, _console(dom.stderr)


def test_console_check_sees_an_error(tmp_path):
    """The check below can fail: a page with a script error is caught."""
    bad = tmp_path / "bad.html"
    bad.write_text("<html><body><script>console.error('boom'); nope();</script></body></html>")
    _, console = _page(bad)
    assert any("boom" in c for c in console) and any("nope" in c for c in console)


def test_report_page_renders_in_chromium(tiny_report, tmp_path):  # noqa: F811
    from PIL import Image

    out, _ = tiny_report
    index = out / "index.html"
    dom, console = _page(index)
    assert console == [], console
    # the viewer ran, drew its first panel and read lit pixels back
    viewers = re.findall(r'class="pcv" id="viewer-[^>]*>', dom)
    assert len(viewers) == 1
    drawn = re.search(r'data-drawn="(\d+)"', viewers[0])
    assert 'data-status="drawn"' in viewers[0] and drawn and int(drawn.group(1)) > 500
    # every picture the page shows exists and decodes
    srcs = re.findall(r'<img src="([^"]+)"', dom)
    assert srcs
    for src in srcs:
        with Image.open(out / src) as im:
            assert im.size[0] > 100
    # the screenshot is a page, not a blank window
    shot = tmp_path / "shot.png"
    res = _chromium(f"--screenshot={shot}", index.as_uri())
    assert res.returncode == 0 and shot.exists(), res.stderr[-2000:]
    with Image.open(shot) as im:
        a = np.asarray(im.convert("L"), dtype=float)
    assert (a < 200).mean() > 0.01 and a.std() > 10
