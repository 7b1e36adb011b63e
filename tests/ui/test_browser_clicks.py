"""The station page in real headless Chromium: a second click taken onto the target found along
the epipolar line (or onto the line), and the one-camera flow (a click on the focal plane plus
an offset, closed loop) on the thesis platform seen by its top camera alone."""

from __future__ import annotations

import numpy as np
import pytest

from support.browser import open_page, serve_station, unavailable_reason
from support.station_files import write_truth_calibration

pytestmark = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))


@pytest.fixture
def two_cameras(netns, tmp_path):
    pytest.importorskip("starlette", reason="needs Starlette (pip install 'microcal[ui]')")
    yield from serve_station(str(write_truth_calibration(tmp_path / "calibration.json")))


@pytest.fixture
def one_camera(netns, tmp_path):
    pytest.importorskip("starlette", reason="needs Starlette (pip install 'microcal[ui]')")
    path = write_truth_calibration(tmp_path / "calibration.json", cameras=("top",))
    yield from serve_station(str(path))


def _click_px(page, live, camera: str, q_px) -> None:
    """Click where the full-resolution pixel ``q_px`` shows in ``camera``'s view."""
    box = page.locator(f'canvas.live[data-camera="{camera}"]').bounding_box()
    k = box["width"] / live.models[camera].image_size_px[0]
    page.mouse.click(box["x"] + (q_px[0] + 0.5) * k, box["y"] + (q_px[1] + 0.5) * k)


def _project(live, camera: str, p_um):
    return live.models[camera].project(np.asarray(p_um, dtype=float)[None, :])[0]


def test_a_second_click_is_taken_onto_the_target_along_the_line_or_onto_the_line(two_cameras):
    server, browser = two_cameras
    live = server.live
    page = open_page(browser, server.url)
    tip = live.truth()
    # on the tip in the top view, then a few pixels beside it in the side view: the tip found
    _click_px(page, live, "top", _project(live, "top", tip))
    page.wait_for_function("(window.microcal.curves.side || []).length > 10")
    _click_px(page, live, "side", _project(live, "side", tip) + [5.0, 4.0])
    page.wait_for_function("window.microcal.target !== null")
    snap = page.evaluate("window.microcal.target.snapped.side")
    assert snap["how"] == "feature"
    assert snap["line_px"] < 4.0
    assert np.linalg.norm(np.array(snap["q_px"]) - _project(live, "side", tip)) < 0.5
    assert "side: on the target found" in page.inner_text("#snap-text")
    target = np.array(page.evaluate("window.microcal.target.target_um"))
    assert np.linalg.norm(target - tip) < 100.0  # the top click: one displayed pixel, ~50 µm
    # far from the tip in the side view: the click goes onto the line
    _click_px(page, live, "top", _project(live, "top", tip))
    page.wait_for_function("window.microcal.target === null")
    _click_px(page, live, "side", _project(live, "side", tip) + [60.0, 40.0])
    page.wait_for_function("window.microcal.target !== null")
    snap = page.evaluate("window.microcal.target.snapped.side")
    assert snap["how"] == "line"
    assert "side: the click projected onto the line" in page.inner_text("#snap-text")
    assert page.evaluate("window.microcal.target.residual_px.side") < 0.5  # the rays meet
    assert live.moves_started == 0


@pytest.mark.slow
def test_one_camera_click_on_the_focal_plane_and_go_closed_loop(one_camera):
    server, browser = one_camera
    live = server.live
    page = open_page(browser, server.url, cameras=("top",))
    assert page.locator("canvas.live").count() == 1
    assert "One camera" in page.inner_text("#hint")
    assert "focal plane:" in page.inner_text("#focal-text")
    goal = np.array([3600.0, 2600.0, 1800.0])
    offset = float(live.models["top"].depth_um(goal[None, :])[0] - live.focal_plane.depth_um)
    page.fill("#offset", f"{offset:.3f}")
    _click_px(page, live, "top", _project(live, "top", goal))
    page.wait_for_function("window.microcal.target !== null")
    target = np.array(page.evaluate("window.microcal.target.target_um"))
    assert np.linalg.norm(target - goal) < 60.0  # one displayed pixel: ~2.5 camera pixels
    # placed to the camera pixel in the zoom (the same depth)
    page.wait_for_function(
        "(() => { const v = window.microcal.views.top, c = window.microcal.clicks.top;"
        " return v.zoomCorner !== undefined && v.zoomCorner[0] === Math.round(c[0]) - 80; })()"
    )
    corner = page.evaluate("window.microcal.views.top.zoomCorner")
    q = _project(live, "top", goal)
    page.locator("canvas.zoom").click(
        position={"x": q[0] - corner[0] + 0.5, "y": q[1] - corner[1] + 0.5}
    )
    page.wait_for_function("window.microcal.std.top === 0.5")
    page.wait_for_function(
        f"window.microcal.target !== null && window.microcal.target.target_um[0] !== {target[0]}"
    )
    target = np.array(page.evaluate("window.microcal.target.target_um"))
    assert np.linalg.norm(target - goal) < 25.0  # half a camera pixel: ~10 µm
    assert "on the focal plane" in page.inner_text("#snap-text")
    page.select_option("#mode", "closed")
    page.fill("#tolerance", "0.3")
    page.click("#go")
    page.wait_for_function(
        "window.microcal.state && window.microcal.state.arrival", timeout=120_000
    )
    assert live.wait(60.0)
    arrival = live.state()["arrival"]
    # across the camera's axis measured; along it the model: within a few µm by truth
    assert arrival["truth_error_um"] < 3.0
    assert page.inner_text("#error") == ""
