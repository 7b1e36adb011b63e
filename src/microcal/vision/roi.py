"""Regions of interest: where the board is, will be, or was stored, in a camera's image.

- :class:`RoiPredictor` predicts the board's region from the commanded joints (an affine
  map joints -> image learnt from the poses seen so far);
- :func:`box_around` is the search box around a standing board for the next frames;
- :func:`frames_from_region` puts frames stored as a region back into frames of full size.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray

__all__ = ["RoiPredictor", "box_around", "frames_from_region"]


class RoiPredictor:
    """Where the board will be in a camera's image, from the commanded joints.

    After ``min_poses`` successful detections, an affine map joints -> virtual point (px) is
    fitted by least squares and refitted as poses come; the region is the board's size in
    pixels around the prediction, with a margin.
    """

    def __init__(self, margin_px: float = 40.0, min_poses: int = 4) -> None:
        self.margin_px = margin_px
        self.min_poses = min_poses
        self._d: list[FloatArray] = []
        self._q: list[FloatArray] = []
        self._half: FloatArray | None = None
        self._A: FloatArray | None = None

    def add(self, d_um: FloatArray, corners_px: FloatArray) -> None:
        self._d.append(np.append(d_um, 1.0))
        self._q.append(corners_px.mean(axis=0))
        half = (corners_px.max(axis=0) - corners_px.min(axis=0)) / 2
        self._half = half if self._half is None else np.maximum(self._half, half)
        if len(self._d) >= self.min_poses:
            self._A = np.linalg.lstsq(np.array(self._d), np.array(self._q), rcond=None)[0]

    def predict(self, d_um: FloatArray) -> tuple[int, int, int, int] | None:
        if self._A is None or self._half is None:
            return None
        centre = np.append(d_um, 1.0) @ self._A
        half = 1.6 * self._half + self.margin_px
        lo, hi = np.floor(centre - half), np.ceil(centre + half)
        return int(lo[0]), int(lo[1]), int(hi[0]) + 1, int(hi[1]) + 1


def frames_from_region(
    frames: Sequence[NDArray[np.generic]], offset_px: Sequence[int], full_size_px: Sequence[int]
) -> list[NDArray[np.generic]]:
    """Put frames stored as a region back into frames of full size.

    Parameters
    ----------
    frames : sequence of (h, w) arrays
        The stored regions.
    offset_px : (2,) int
        x0, y0 of the region in the full frame.
    full_size_px : (2,) int
        Width and height of the full frame.

    Returns
    -------
    list of (H, W) arrays
        Each region pasted on a frame filled with the region's median grey level.
    """
    (x0, y0), (w, h) = offset_px, full_size_px
    full = []
    for f in frames:
        canvas = np.full((h, w), np.median(np.asarray(f, dtype=np.float64)), dtype=f.dtype)
        canvas[y0 : y0 + f.shape[0], x0 : x0 + f.shape[1]] = f
        full.append(canvas)
    return full


def box_around(corners_px: FloatArray, margin_px: float = 30.0) -> tuple[int, int, int, int]:
    """A search box (x0, y0, x1, y1) around a board's corners, for the next frames of a pose.

    While the manipulator stands still the board stays put: the box is 1.6x the board's
    extent plus ``margin_px``.
    """
    half = (corners_px.max(axis=0) - corners_px.min(axis=0)) * 0.8 + margin_px
    centre = corners_px.mean(axis=0)
    lo, hi = np.floor(centre - half).astype(int), np.ceil(centre + half).astype(int)
    return int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])
