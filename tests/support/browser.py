"""Headless Chromium for the station page's tests: Debian's chromium driven by Playwright,
never a browser Playwright downloads."""

from __future__ import annotations

import os
import shutil

CHROMIUM = "/usr/bin/chromium"
#: as root with no sandbox, no GPU, and none of the browser's own network traffic
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run",
        "--disable-component-update", "--disable-sync", "--disable-quic"]  # fmt: skip


def chromium_path() -> str | None:
    """Debian's chromium, or another on PATH; None when there is none."""
    if os.access(CHROMIUM, os.X_OK):
        return CHROMIUM
    return shutil.which("chromium")


def unavailable_reason() -> str | None:
    """Why the browser tests cannot run here, or None."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "needs Playwright (pip install 'microcal[dev]')"
    if chromium_path() is None:
        return "needs Debian's chromium (apt-get install chromium; .ci/run installs it)"
    return None
