"""Prints an HTML page to PDF with headless Chromium (``doorlab report --pdf``).

The page is self-contained (images as data URIs), so Chromium loads nothing but the file;
host resolution is disabled anyway, so printing never touches the network.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from doorlab.errors import OutputError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
"""Executables tried, in order."""
DEBIAN_PACKAGE = "chromium"
"""The Debian/Ubuntu package that provides headless Chromium."""
PRINT_TIMEOUT_S = 120.0
"""Time limit of one print [s] (a report page prints in a few seconds)."""
HEADLESS_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--host-resolver-rules=MAP * ~NOTFOUND",
)
"""Headless Chromium that reaches no network (no background services, no host resolution);
the pages load nothing but their own file. Shared by the PDF printer and the browser tests."""


def find_chromium() -> str:
    """Path of a Chromium executable.

    Raises:
        OutputError: None installed (the message names the package to install).
    """
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    raise OutputError(
        "--pdf needs headless Chromium, which is not installed: "
        f"apt-get install {DEBIAN_PACKAGE} (Debian/Ubuntu package {DEBIAN_PACKAGE!r})"
    )


def print_pdf(html: str | Path, pdf: str | Path, *, chromium: str | None = None) -> Path:
    """Prints ``html`` to ``pdf`` (written atomically) with headless Chromium.

    Args:
        html: A self-contained HTML file.
        pdf: The PDF to write.
        chromium: The browser executable (default: :func:`find_chromium`).

    Raises:
        OutputError: No Chromium, or it failed or wrote no PDF.
    """
    html, pdf = Path(html).resolve(), Path(pdf)
    binary = chromium or find_chromium()
    with tempfile.TemporaryDirectory(prefix="doorlab_pdf_") as tmp:
        out = Path(tmp) / "page.pdf"
        command = [
            binary,
            *HEADLESS_FLAGS,
            f"--user-data-dir={Path(tmp) / 'profile'}",
            "--no-pdf-header-footer",
            f"--print-to-pdf={out}",
            html.as_uri(),
        ]
        try:
            done = subprocess.run(
                command, capture_output=True, text=True, timeout=PRINT_TIMEOUT_S, check=False
            )
        except subprocess.TimeoutExpired:
            raise OutputError(
                f"Chromium did not print {html} within {PRINT_TIMEOUT_S:.0f} s"
            ) from None
        if not out.is_file() or out.stat().st_size == 0:
            last = (done.stderr or "").strip().splitlines()[-1:] or ["no output"]
            raise OutputError(f"Chromium printed no PDF (exit {done.returncode}): {last[0]}")
        try:
            pdf.parent.mkdir(parents=True, exist_ok=True)
            staged = pdf.with_name(pdf.name + ".tmp")
            shutil.copyfile(out, staged)
            staged.replace(pdf)
        except OSError as e:
            raise OutputError(f"cannot write {pdf}: {e.strerror or e}") from None
    return pdf
