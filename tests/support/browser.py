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


def serve_station(calibration: str, frames: int = 2):
    """Yield (server, browser): the simulated thesis station with ``calibration`` served on
    127.0.0.1 and a headless Chromium; both stopped afterwards. Use inside a fixture that
    made the test's own network namespace."""
    from playwright.sync_api import sync_playwright

    from microcal.ui.serve import start_server
    from microcal.workflows.live import open_live_station

    live = open_live_station("sim", calibration, seed=0, frames=frames)
    server = start_server(live, "127.0.0.1", 0)
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium_path(), args=ARGS)
            try:
                yield server, browser
            finally:
                browser.close()
    finally:
        server.stop()


def open_page(browser, url: str, cameras=("top", "side"), height_px: int = 1000):
    """A page of a browser context of its own (its own cookies: another browser), once every
    camera in ``cameras`` has shown a few frames."""
    page = browser.new_context(viewport={"width": 1700, "height": height_px}).new_page()
    page.goto(url)
    page.wait_for_function(" && ".join(f"window.microcal.frames.{c} > 2" for c in cameras))
    return page
