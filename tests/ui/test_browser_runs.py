"""Runs from the station page in real headless Chromium: an acquisition with its progress bar,
cancelled and resumed from the page, a check that joins the health panel's plot, a run that
fails said in words, and a watching browser that cannot start or cancel anything."""

from __future__ import annotations

import pytest

from support.browser import open_page, serve_station, unavailable_reason
from support.station_files import write_truth_calibration

pytestmark = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))


@pytest.fixture
def served(netns, tmp_path):
    pytest.importorskip("starlette", reason="needs Starlette (pip install 'microcal[ui]')")
    calibration = str(write_truth_calibration(tmp_path / "calibration.json"))
    yield from serve_station(calibration, frames=1)


def _run(page) -> dict:
    return page.evaluate("window.microcal.run")


@pytest.mark.slow
def test_an_acquisition_cancelled_and_resumed_from_the_page_then_a_check(served):
    from microcal.formats.run_directory import RunDirectory

    server, browser = served
    live = server.live
    page = open_page(browser, server.url, height_px=1100)
    page.wait_for_function("window.microcal.role === 'control'")
    watcher = open_page(browser, server.url, height_px=1100)
    watcher.wait_for_function("window.microcal.role === 'watch'")
    assert watcher.locator("#run-start").is_disabled()
    page.select_option("#run-kind", "acquire")
    page.fill("#run-poses", "12")
    page.fill("#run-name", "from-page")  # the command's frames: poses slow enough to cancel
    page.click("#run-start")
    page.wait_for_function("window.microcal.run && window.microcal.run.done >= 2", timeout=120_000)
    assert page.locator("#run-start").is_disabled()
    assert float(page.get_attribute("#run-bar", "max")) == 12.0
    # the watching browser sees the progress but cannot cancel
    watcher.wait_for_function("window.microcal.run && window.microcal.run.status === 'running'")
    assert watcher.locator("#run-cancel").is_disabled()
    answer = watcher.evaluate(
        """fetch('/api/run/cancel', {method: 'POST', headers: {'Content-Type': 'application/json'},
                                     body: '{}'}).then((r) => r.status)"""
    )
    assert answer == 403
    page.click("#run-cancel")
    page.wait_for_function("window.microcal.run.status === 'cancelled'", timeout=120_000)
    out = live.calibration_path.with_name("station-runs") / "from-page"
    stored = len(RunDirectory(out).journal())
    assert 2 <= stored < 12
    assert page.locator("#run-resume").is_visible()
    assert f"{stored} of 12 poses stored" in page.inner_text("#run-message")
    assert f"microcal acquire --out {out} --resume" in page.inner_text("#run-message")
    page.click("#run-resume")
    page.wait_for_function(
        f"window.microcal.run.status === 'running' && window.microcal.run.done > {stored}",
        timeout=120_000,
    )
    page.click("#run-cancel")
    page.wait_for_function("window.microcal.run.status === 'cancelled'", timeout=120_000)
    assert len(RunDirectory(out).journal()) > stored
    # a check: its verdict joins the health panel
    page.select_option("#run-kind", "check")
    page.fill("#run-frames", "2")  # the check's own default is 20 per pose
    page.fill("#run-name", "")
    page.click("#run-start")
    page.wait_for_function("window.microcal.run.kind === 'check' && window.microcal.run.status "
                           "=== 'done'", timeout=240_000)  # fmt: skip
    page.wait_for_function(
        "document.querySelector('#health-check').textContent.includes('1 check')"
    )
    assert "verdict" in page.inner_text("#run-message")
    # a name that is not a plain word: refused in words, nothing starts
    page.select_option("#run-kind", "acquire")
    page.fill("#run-name", "../elsewhere")
    page.click("#run-start")
    page.wait_for_function(
        "document.querySelector('#run-message').textContent.includes('plain word')"
    )
    page.wait_for_timeout(2500)  # the page's state comes twice: the refusal stays in words
    assert "plain word" in page.inner_text("#run-message")
    assert _run(page)["kind"] == "check"
    assert page.inner_text("#error") == ""
