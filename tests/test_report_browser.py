"""The report page renders in a real browser: headless Chromium loads a copy of index.html.

A tiny inline script, added to the TEST COPY only (the page itself has no JavaScript), writes
into the DOM whether every image decoded (``complete`` and ``naturalWidth > 0``) and every
table has rows and a visible height; ``--dump-dom`` prints the DOM after the load event.
The browser runs offline-minded: no network services, a throw-away profile.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from report_fixtures import single_run_report

from doorlab.runtime.pdf import HEADLESS_FLAGS

CHECK_SCRIPT = """
<script>
window.addEventListener("load", () => {
  const images = Array.from(document.images);
  const tables = Array.from(document.querySelectorAll("table"));
  const result = {
    images: images.length,
    broken_images: images.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt),
    tables: tables.length,
    empty_tables: tables
      .filter(t => t.rows.length < 2 || t.getBoundingClientRect().height <= 0)
      .map(t => t.id || "(no id)"),
  };
  const out = document.createElement("pre");
  out.id = "render-check";
  out.textContent = JSON.stringify(result);
  document.body.appendChild(out);
});
</script>
"""

BROWSER_TIMEOUT_S = 60


def chromium() -> str | None:
    """Path of the Chromium binary, or None."""
    if Path("/usr/bin/chromium").is_file():
        return "/usr/bin/chromium"
    return shutil.which("chromium") or shutil.which("chromium-browser")


def render_check(page: str, tmp_path: Path) -> dict:
    """Loads ``page`` in headless Chromium and returns what CHECK_SCRIPT saw there: counts of
    images and tables, the broken images and the empty tables (skips without Chromium)."""
    binary = chromium()
    if binary is None:
        pytest.skip("chromium not installed: apt-get install chromium")
    copy = tmp_path / "index_check.html"
    copy.write_text(page.replace("</body>", CHECK_SCRIPT + "</body>"), encoding="utf-8")
    command = [
        binary,
        *HEADLESS_FLAGS,
        f"--user-data-dir={tmp_path / 'profile'}",
        "--virtual-time-budget=5000",
        "--dump-dom",
        copy.as_uri(),
    ]
    done = subprocess.run(
        command, capture_output=True, text=True, timeout=BROWSER_TIMEOUT_S, check=False
    )
    match = re.search(r'<pre id="render-check">(.*?)</pre>', done.stdout, flags=re.S)
    assert match, f"no render check in the DOM (exit {done.returncode}): {done.stderr[-2000:]}"
    return json.loads(match.group(1).replace("&quot;", '"').replace("&amp;", "&"))


@pytest.mark.slow
def test_every_image_and_table_renders_in_chromium(tmp_path: Path):
    """In headless Chromium every embedded image decodes and every table renders with rows."""
    if chromium() is None:
        pytest.skip("chromium not installed: apt-get install chromium")
    page = (single_run_report() / "index.html").read_text(encoding="utf-8")
    expected_images = len(re.findall(r"<img\b", page))
    expected_tables = len(re.findall(r"<table\b", page))
    result = render_check(page, tmp_path)
    assert result["images"] == expected_images >= 5
    assert result["broken_images"] == []
    assert result["tables"] == expected_tables >= 3
    assert result["empty_tables"] == []
