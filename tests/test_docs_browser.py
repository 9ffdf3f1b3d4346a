"""The built site in a real browser (headless Chromium from the distribution's packages): at desktop width no page
scrolls sideways, no table overflows its box, every picture loads, and no page is taller than a reader can take.

Each page is loaded in a 1280 x 800 frame of a checking page served with the site on 127.0.0.1; the checking page
measures the frame's document and writes what it found into its own DOM, which ``chromium --dump-dom`` prints.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
WIDTH, HEIGHT = 1280, 800
#: The tallest page a reader should meet, in CSS pixels at desktop width.
MAX_PAGE_PX = 40_000
BROWSERS = ("chromium", "chromium-browser", "google-chrome")

pytestmark = pytest.mark.slow

CHECKER = r"""<!doctype html><html><body><pre id="result">pending</pre>
<iframe id="frame" width="%(width)d" height="%(height)d"></iframe>
<script>
const pages = %(pages)s;
const found = [];
const frame = document.getElementById("frame");
function measure(path) {
  const doc = frame.contentDocument, root = doc.documentElement;
  const wide = [...doc.querySelectorAll("table")].filter(t => {
    const box = t.closest(".md-typeset__scrollwrap") || t.parentElement;
    return t.scrollWidth > box.clientWidth + 1;
  }).map(t => t.rows[0].innerText.replace(/\s+/g, " ").slice(0, 80));
  const broken = [...doc.images].filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.getAttribute("src"));
  found.push({path, scroll: root.scrollWidth > root.clientWidth + 1, wide, broken, height: root.scrollHeight,
              tables: doc.querySelectorAll("table").length});
}
function next(i) {
  if (i >= pages.length) { document.getElementById("result").textContent = JSON.stringify(found); return; }
  frame.onload = () => setTimeout(() => { measure(pages[i]); next(i + 1); }, 300);
  frame.src = pages[i];
}
next(0);
</script></body></html>
"""


def _browser() -> str | None:
    return next((path for name in BROWSERS if (path := shutil.which(name))), None)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.fixture(scope="module")
def measured(tmp_path_factory: pytest.TempPathFactory) -> list[dict]:
    browser = _browser()
    if browser is None:
        pytest.skip(f"no headless browser here ({', '.join(BROWSERS)}; Debian: apt install chromium)")
    pytest.importorskip("mkdocs", reason="needs the [dev] extra")
    site = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    build = [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)]
    done = subprocess.run(build, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    pages = sorted("/" + p.relative_to(site).as_posix() for p in site.rglob("index.html") if p.parent != site / "404")
    (site / "check.html").write_text(CHECKER % {"width": WIDTH, "height": HEIGHT, "pages": json.dumps(pages)})
    port = _free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1", "--directory", str(site)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        profile = tmp_path_factory.mktemp("chromium-profile")
        command = [browser, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={profile}"]
        command += ["--virtual-time-budget=120000", "--dump-dom", f"http://127.0.0.1:{port}/check.html"]
        dom = subprocess.run(command, capture_output=True, text=True, timeout=300).stdout
    finally:
        server.terminate()
        server.wait(10)
    match = re.search(r'<pre id="result">(.*?)</pre>', dom, re.DOTALL)
    assert match and match[1].startswith("["), f"the checking page did not finish: {dom[-2000:]}"
    results = json.loads(match[1].replace("&quot;", '"').replace("&amp;", "&"))
    assert len(results) == len(pages)
    return results


def test_no_page_scrolls_sideways_at_desktop_width(measured: list[dict]) -> None:
    assert [r["path"] for r in measured if r["scroll"]] == []


def test_no_table_overflows_its_box_at_desktop_width(measured: list[dict]) -> None:
    assert {r["path"]: r["wide"] for r in measured if r["wide"]} == {}  # each overflowing table's header row


def test_every_picture_loads(measured: list[dict]) -> None:
    assert {r["path"]: r["broken"] for r in measured if r["broken"]} == {}


def test_no_page_is_taller_than_a_reader_can_take(measured: list[dict]) -> None:
    assert {r["path"]: r["height"] for r in measured if r["height"] > MAX_PAGE_PX} == {}
