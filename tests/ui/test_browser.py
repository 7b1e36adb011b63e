"""The station page in real headless Chromium (Debian's, driven by Playwright), served on
loopback inside the test's own network namespace: the click-to-go flow on the thesis preset,
a target outside the limits refused on the page, and a second browser that only watches."""

from __future__ import annotations

import numpy as np
import pytest

from support.browser import open_page, serve_station, unavailable_reason
from support.station_files import write_truth_calibration

pytestmark = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))


@pytest.fixture(scope="module")
def calibration(tmp_path_factory) -> str:
    return str(write_truth_calibration(tmp_path_factory.mktemp("browser") / "calibration.json"))


@pytest.fixture
def served(netns, calibration):
    """(server, browser): the thesis preset's page on 127.0.0.1 and a headless Chromium."""
    pytest.importorskip("starlette", reason="needs Starlette (pip install 'microcal[ui]')")
    yield from serve_station(calibration)


def _click_at(page, live, camera: str, p_um) -> None:
    """Click where the point ``p_um`` in {G} shows in ``camera``'s view."""
    q = live.models[camera].project(np.asarray(p_um, dtype=float)[None, :])[0]
    box = page.locator(f'canvas.live[data-camera="{camera}"]').bounding_box()
    k = box["width"] / live.models[camera].image_size_px[0]
    page.mouse.click(box["x"] + (q[0] + 0.5) * k, box["y"] + (q[1] + 0.5) * k)


@pytest.mark.slow
def test_click_in_two_views_go_closed_loop_and_the_tip_arrives_by_truth(served):
    server, browser = served
    live = server.live
    page = open_page(browser, server.url)
    assert page.inner_text("#role") == "this browser controls"
    # a point above the workspace: refused on the page, the go button stays off, nothing moves
    _click_at(page, live, "top", [3000.0, 3000.0, 9000.0])
    page.wait_for_function("(window.microcal.curves.side || []).length > 10")
    _click_at(page, live, "side", [3000.0, 3000.0, 9000.0])
    page.wait_for_function("window.microcal.target !== null")
    assert "outside the soft limits" in page.inner_text("#refusal")
    assert page.locator("#go").is_disabled()
    assert live.moves_started == 0
    # the tip target in the top view, then on the epipolar line in the side view
    _click_at(page, live, "top", [3600.0, 2600.0, 1800.0])
    page.wait_for_function("window.microcal.target === null && window.microcal.curves.side")
    _click_at(page, live, "side", [3600.0, 2600.0, 1800.0])
    page.wait_for_function("window.microcal.target !== null")
    # refined in the side view's zoom (full resolution): the same view's click is replaced
    before = page.evaluate("window.microcal.target.target_um")
    page.wait_for_function(  # the zoom cut around the side view's click
        "(() => { const v = window.microcal.views.side, c = window.microcal.clicks.side;"
        " return v.zoomCorner !== undefined && v.zoomCorner[0] === Math.round(c[0]) - 80"
        " && v.zoomCorner[1] === Math.round(c[1]) - 80; })()"
    )
    page.locator('figure[data-camera="side"] canvas.zoom').click(position={"x": 80, "y": 80})
    page.wait_for_function("window.microcal.std.side === 0.5")
    page.wait_for_function(
        f"window.microcal.target !== null && window.microcal.target.target_um[0] !== {before[0]}"
    )
    assert sorted(page.evaluate("Object.keys(window.microcal.clicks)")) == ["side", "top"]
    target = np.array(page.evaluate("window.microcal.target.target_um"))
    assert np.linalg.norm(target - [3600.0, 2600.0, 1800.0]) < 200.0  # a click is a few px
    assert page.inner_text("#refusal") == ""
    page.select_option("#mode", "closed")
    page.fill("#tolerance", "0.5")
    page.click("#go")
    page.wait_for_function(
        "window.microcal.state && window.microcal.state.arrival", timeout=120_000
    )
    assert live.wait(60.0)
    true_um = live.truth()
    assert np.linalg.norm(true_um - target) < 1.0
    page.wait_for_function("document.querySelector('#arrival').textContent.includes('by truth')")
    assert page.inner_text("#error") == ""


@pytest.mark.slow
def test_a_second_browser_watches_and_cannot_move_anything(served):
    server, browser = served
    live = server.live
    first = open_page(browser, server.url)
    first.wait_for_function("window.microcal.role === 'control'")
    second = open_page(browser, server.url)
    second.wait_for_function("window.microcal.role === 'watch'")
    assert second.inner_text("#role") == "watching: another browser controls"
    assert second.locator("#go").is_disabled()
    _click_at(second, live, "top", [3600.0, 2600.0, 1800.0])
    assert second.inner_text("#error") == "this browser watches; another one controls the station"
    answer = second.evaluate(
        """fetch('/api/go', {method: 'POST', headers: {'Content-Type': 'application/json'},
                             body: JSON.stringify({target_um: [3600, 2600, 1800]})})
           .then(async (r) => [r.status, (await r.json()).error])"""
    )
    assert answer == [403, "refused: another browser controls this station; this one watches"]
    assert live.moves_started == 0
    second.click("#stop")  # any browser may stop
    second.wait_for_function("document.querySelector('#activity').textContent.includes('stopped')")
    assert live.manipulator.halted
