"""The acquisition's view of a target in a frame: a board's corners or a tool's apex, and the
region worth storing."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.sim import platform
from microcal.vision.roi import frames_from_region
from microcal.vision.target_points import TIP_REGION_HALF_PX, find_target
from microcal.vision.tip import detect_tip


def _frame(preset: str, overrides: dict[str, object] | None = None, camera: str = "top"):  # type: ignore[no-untyped-def]
    plat = platform(preset, seed=2, overrides=overrides)
    m = plat.manipulator
    m.move_to_um(np.array([3000.0, 5000.0, 2000.0]))
    m.wait_until_stopped(plat.clock, timeout_s=60)
    plat.clock.sleep(5.0)
    cam = plat.cameras[camera]
    frame = cam.grab()
    assert cam.last_truth is not None
    return plat, frame, cam.last_truth.features_px[0]


def test_a_board_gives_its_corners_and_a_margin_of_squares() -> None:
    plat, frame, truth = _frame("thesis")
    found = find_target(frame, plat.scene.board)
    assert found is not None
    assert found.complete
    assert found.points_px.shape == (12, 2)
    x0, _y0, x1, _y1 = found.region_px
    square = float(np.median(np.linalg.norm(np.diff(found.points_px, axis=0), axis=1)))
    assert x0 <= truth[:, 0].min() - 2.5 * square
    assert x1 >= truth[:, 0].max() + 2.5 * square


@pytest.mark.parametrize("camera", ["top", "side"])
def test_a_tool_gives_its_apex_and_a_region_to_the_image_edge_along_its_shank(camera) -> None:
    plat, frame, truth = _frame("thesis-tip", {"board": "tip:needle:20:5"}, camera)
    found = find_target(frame, plat.scene.board)
    assert found is not None
    assert found.complete
    assert found.points_px.shape == (1, 2)
    assert float(np.linalg.norm(found.points_px[0] - truth[0])) < 2.0
    x0, y0, x1, y1 = found.region_px
    h, w = frame.shape[:2]
    assert x1 == w  # the shank runs along +x to the edge
    assert x0 <= truth[0, 0] - TIP_REGION_HALF_PX + 1
    # put back together from the region, the frame still shows one tool entering the field
    (whole,) = frames_from_region([frame[y0:y1, x0:x1]], (x0, y0), (w, h))
    # the method find_target takes for a needle whose spec gives its size (its vertex path)
    again = detect_tip(whole, plat.scene.board, method="model fit")  # type: ignore[arg-type]
    assert again.found
    # the model fit sees another background beyond the region: within a pixel on 22 µm pixels
    np.testing.assert_allclose(again.apex_px, found.points_px[0], atol=1.0)


def test_no_tool_no_target() -> None:
    plat, frame, _ = _frame("thesis-tip", {"board": "tip:needle:20:5"})
    blank = np.full_like(frame, int(np.median(frame)))
    assert find_target(blank, plat.scene.board) is None
