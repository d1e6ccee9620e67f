"""Render the report in headless Chromium: every figure decodes, the page logs no errors.

The report itself has no JavaScript. The test serves a copy of ``index.html`` with a small
probe script added first in ``<head>`` (it records ``window.onerror``, unhandled
rejections, ``console.error`` and resource-load failures) and last in ``<body>`` (after
``load`` it writes, into the DOM, every image's decoded size and the recorded errors).
``chromium --dump-dom`` then prints the DOM, which the test parses. Network access is
blocked by a proxy that does not exist, so a report needing anything online fails.

Skipped, with the reason, where Debian's ``chromium`` is not installed (``.ci/run``
installs it).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest
from test_demo import MODEL_FIGURES, make_demo

RAW_FIGURES = ("temperature", "raw-output", "allan", "plateau-noise")

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium not installed (apt-get install chromium; .ci/run does)"
)

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    # Offline: every request that is not file:/data: goes to a dead proxy and fails.
    "--proxy-server=127.0.0.1:9",
    "--proxy-bypass-list=<-loopback>",
]

HEAD_PROBE = """<script>
window.__errors = [];
window.addEventListener('error', function (e) {
  var t = e.target;
  if (t && t !== window && (t.src || t.href)) {
    window.__errors.push('resource failed: ' + String(t.src || t.href).slice(0, 80));
  } else { window.__errors.push('error: ' + e.message); }
}, true);
window.addEventListener('unhandledrejection', function (e) {
  window.__errors.push('rejection: ' + e.reason);
});
(function () { var ce = console.error;
  console.error = function () { window.__errors.push('console.error: ' +
    Array.prototype.join.call(arguments, ' ')); ce.apply(console, arguments); }; })();
</script>"""

TAIL_PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.map.call(document.images, function (im) {
    var fig = im.closest('figure');
    return {id: fig ? fig.id : '', w: im.naturalWidth, h: im.naturalHeight,
            shown: im.getBoundingClientRect().width, complete: im.complete};
  });
  var pre = document.createElement('pre');
  pre.id = '__probe';
  pre.textContent = JSON.stringify({errors: window.__errors, images: imgs,
    sections: document.querySelectorAll('section').length});
  document.body.appendChild(pre);
});
</script>"""


def _chromium(args: list[str], timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    with tempfile.TemporaryDirectory(prefix="gyrolab-chromium-") as profile:
        return subprocess.run(
            [str(CHROMIUM), *FLAGS, f"--user-data-dir={profile}", *args],
            capture_output=True,
            text=True,
            timeout=timeout,
            env={**os.environ, "HOME": profile},
        )


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo of tests/test_demo.py (made once per session, whichever test asks first)."""
    return make_demo(tmp_path_factory)


def probe(html_path: Path) -> dict:
    """Load ``html_path`` (a probed copy) in Chromium and return what the probe saw."""
    html = html_path.read_text(encoding="utf-8")
    probed = html.replace("<head>", "<head>" + HEAD_PROBE, 1).replace(
        "</body>", TAIL_PROBE + "</body>", 1
    )
    copy = html_path.with_name("probed.html")
    copy.write_text(probed, encoding="utf-8")
    res = _chromium(["--virtual-time-budget=10000", "--dump-dom", copy.as_uri()])
    m = re.search(r'<pre id="__probe">(.*?)</pre>', res.stdout, re.S)
    assert m, f"probe output missing; chromium stderr tail: {res.stderr[-2000:]}"
    return json.loads(
        m.group(1)
        .replace("&quot;", '"')
        .replace("&amp;", "&")
        .replace("&lt;", "<")
        .replace("&gt;", ">")
    )


def screenshot(html_path: Path, png: Path, size: str = "1200,2600") -> None:
    res = _chromium([f"--window-size={size}", f"--screenshot={png}", html_path.as_uri()])
    assert png.is_file() and png.stat().st_size > 10_000, res.stderr[-2000:]


def test_probe_catches_errors(tmp_path: Path) -> None:
    """The probe is real: a page with a script error and a missing image is caught."""
    page = tmp_path / "bad.html"
    page.write_text(
        "<!DOCTYPE html><html><head></head><body><figure id='f'>"
        "<img src='missing.png'></figure><script>undefinedFn()</script>"
        "</body></html>"
    )
    seen = probe(page)
    assert any("undefinedFn" in e for e in seen["errors"])
    assert any("resource failed" in e for e in seen["errors"])
    assert seen["images"][0]["w"] == 0


@pytest.mark.parametrize(
    ("report", "figures"),
    [
        ("report", RAW_FIGURES + MODEL_FIGURES),  # held-out run with the model
        ("calibration-report", RAW_FIGURES),  # raw record
    ],
)
def test_report_renders_every_figure_without_errors(
    demo_run: Path, report: str, figures: tuple[str, ...]
) -> None:
    seen = probe(demo_run / report / "index.html")
    assert seen["errors"] == []
    ids = [im["id"] for im in seen["images"]]
    assert sorted(ids) == sorted(f"fig-{f}" for f in figures)
    for im in seen["images"]:
        assert im["complete"] and im["w"] > 300 and im["h"] > 150 and im["shown"] > 300, im
    assert seen["sections"] >= (5 if report == "report" else 4)


def test_screenshot(demo_run: Path, tmp_path: Path) -> None:
    """A screenshot of the top of the report is not blank (docs/report.md says how the docs
    image, made the same way from the paper-profile demo, is refreshed)."""
    png = tmp_path / "shot.png"
    screenshot(demo_run / "report" / "index.html", png, size="1200,2250")
    from PIL import Image

    im = Image.open(png).convert("L")
    assert im.size == (1200, 2250)
    hist = im.histogram()
    # mostly white page, but a real share of non-white pixels (text, figures)
    assert sum(hist[:200]) > 0.03 * im.size[0] * im.size[1]
