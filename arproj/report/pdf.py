"""report.pdf: the report printed by headless Chromium (Debian's `chromium` package), as a browser prints it.

Chromium lays out the page with the report's print CSS (A4, page numbers in the @page margin box, headings kept
with what follows) and --print-to-pdf writes it; its own header and footer (date, file URL) are left out.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

NAMES = ("chromium", "chromium-browser", "google-chrome")
TIMEOUT_S = 60.0


def chromium() -> str | None:
    """The headless browser's executable ($ARPROJ_CHROMIUM, else the first of NAMES on PATH), or None (also
    for ARPROJ_CHROMIUM=none: tests of other things skip the 2-3 s a PDF costs)."""
    chosen = os.environ.get("ARPROJ_CHROMIUM")
    if chosen == "none":
        return None
    if chosen:
        return shutil.which(chosen)
    return next((found for name in NAMES if (found := shutil.which(name))), None)


def headless_args(browser: str, profile: str) -> list[str]:
    """The command line every headless run shares: no sandbox (root in a container has none to give), no GPU,
    a throw-away profile, and no first-run, extension or network side tasks."""
    return [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
            f"--user-data-dir={profile}", "--no-first-run", "--disable-extensions", "--disable-background-networking",
            "--disable-sync", "--mute-audio", "--hide-scrollbars"]


def run_headless(browser: str, args: list[str], timeout_s: float = TIMEOUT_S) -> subprocess.CompletedProcess[str]:
    """Chromium headless with `args` after the shared ones, in a fresh profile; RuntimeError when it fails."""
    with tempfile.TemporaryDirectory(prefix="arproj-chromium-") as profile:
        done = subprocess.run([*headless_args(browser, profile), *args], capture_output=True, text=True,
                              timeout=timeout_s)
    if done.returncode != 0:
        raise RuntimeError(f"{browser} exited with status {done.returncode}: {done.stderr.strip()[-400:]}")
    return done


def print_pdf(html: Path, pdf: Path, browser: str) -> Path:
    """Print `html` (its images beside it) to `pdf`; RuntimeError when the browser writes none."""
    pdf.unlink(missing_ok=True)
    run_headless(browser, ["--no-pdf-header-footer", f"--print-to-pdf={pdf.resolve()}",
                           html.resolve().as_uri()])
    if not pdf.is_file() or pdf.stat().st_size == 0:
        raise RuntimeError(f"{browser} wrote no PDF at {pdf}")
    return pdf
