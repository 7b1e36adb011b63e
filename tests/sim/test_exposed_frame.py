"""Frames exposed where they are read (SimCamera.grab_lazy): the same draws and pixels as grab."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import sim
from microcal.vision.detect import detect
from microcal.vision.lazy_frame import detect_in, grab_frame
from microcal.vision.roi import box_around


def _thesis(seed: int, overrides: dict[str, object] | None = None) -> sim.SimPlatform:
    plat = sim.platform("thesis", seed=seed, overrides=overrides)
    plat.manipulator.move_to_um([4000, 4000, 2400])
    plat.manipulator.wait_until_stopped(plat.clock)
    return plat


@pytest.mark.parametrize(
    ("name", "overrides"), [("top", None), ("side", None), ("top", {"top.bit_depth": 12})]
)
def test_lazy_frames_are_the_grabbed_frames_pixel_for_pixel(name, overrides):
    """Two platforms of one seed: one grabs whole frames, the other lazy ones read by region
    and then whole; every pixel and every later frame (the random stream) agree."""
    whole, lazy = _thesis(5, overrides).cameras[name], _thesis(5, overrides).cameras[name]
    for _ in range(3):
        expected = whole.grab()
        frame = lazy.grab_lazy()
        h, w = frame.shape
        assert (h, w) == expected.shape
        # boxes inside the rendered box, across its edge, and in the background alone
        for box in [(0, 0, 40, 30), (w // 3, h // 3, 2 * w // 3, 2 * h // 3), (w - 9, h - 7, w, h)]:
            x0, y0, x1, y1 = box
            np.testing.assert_array_equal(frame.region(*box), expected[y0:y1, x0:x1])
        np.testing.assert_array_equal(frame.full(), expected)
        assert frame.full() is frame.full()  # exposed once
        assert frame.region(0, 0, 5, 5) is not frame.full()  # the caller's own array


def test_a_frame_with_faults_that_paint_anywhere_is_whole_and_the_same():
    faults: dict[str, object] = {"top.faults.glare_rate": 0.5, "top.faults.occlusion_rate": 0.3}
    whole, lazy = _thesis(2, faults).cameras["top"], _thesis(2, faults).cameras["top"]
    for _ in range(4):
        expected = whole.grab()
        np.testing.assert_array_equal(lazy.grab_lazy().full(), expected)


def test_detection_in_a_region_of_a_lazy_frame_equals_detection_in_the_whole_frame():
    plat = _thesis(1)
    whole, lazy, board = plat.cameras["top"], _thesis(1).cameras["top"], plat.scene.board
    image = whole.grab()
    frame = grab_frame(lazy)
    roi = box_around(detect(image, board).q_px)
    expected = detect(image, board, roi=roi)
    got = detect_in(frame, board, roi)
    assert got.found
    assert expected.found
    np.testing.assert_array_equal(got.q_px, expected.q_px)
    np.testing.assert_array_equal(got.ids, expected.ids)
    assert got.quality_px == expected.quality_px
    # a box outside the image: detect's own answer
    h, w = frame.shape
    outside = (w + 10, h + 10, w + 50, h + 50)
    assert detect_in(frame, board, outside).reason == detect(image, board, roi=outside).reason
