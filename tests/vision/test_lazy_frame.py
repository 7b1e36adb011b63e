"""Region frames (vision/lazy_frame.py): arrays wrapped, stored regions pasted where read."""

from __future__ import annotations

import numpy as np

from microcal.vision.lazy_frame import ArrayFrame, detect_in, grab_frame, pasted_frames, pixels_of
from microcal.vision.roi import frames_from_region
from microcal.vision.targets import parse_target


def test_pasted_frames_are_frames_from_region_where_read():
    rng = np.random.default_rng(4)
    stored = [rng.integers(0, 256, (40, 60), dtype=np.uint8) for _ in range(2)]
    offset, size = (30, 20), (160, 120)
    expected = frames_from_region(stored, offset, size)
    lazy = pasted_frames(stored, offset, size)
    for frame, full in zip(lazy, expected, strict=True):
        assert frame.shape == (120, 160)
        # inside the stored region, across its edge, and in the fill alone
        for x0, y0, x1, y1 in [(35, 25, 80, 50), (0, 0, 50, 40), (100, 70, 160, 120)]:
            np.testing.assert_array_equal(frame.region(x0, y0, x1, y1), full[y0:y1, x0:x1])
        np.testing.assert_array_equal(frame.full(), full)
        np.testing.assert_array_equal(frame.region(35, 25, 80, 50), full[25:50, 35:80])


class _Camera:
    def __init__(self, image: np.ndarray) -> None:
        self.image = image

    def grab(self) -> np.ndarray:
        return self.image.copy()


def test_a_camera_without_lazy_frames_gives_its_arrays_wrapped():
    image = np.arange(12 * 16, dtype=np.uint16).reshape(12, 16)
    frame = grab_frame(_Camera(image))
    assert isinstance(frame, ArrayFrame)
    assert frame.shape == (12, 16)
    np.testing.assert_array_equal(frame.region(2, 3, 7, 9), image[3:9, 2:7])
    np.testing.assert_array_equal(pixels_of(frame), image)
    assert pixels_of(image) is image


def test_detect_in_an_array_is_detect():
    board = parse_target("chessboard:4x3:400")
    blank = np.full((60, 80), 128, dtype=np.uint8)
    assert not detect_in(blank, board).found
    assert not detect_in(ArrayFrame(blank), board, (0, 0, 40, 30)).found
