"""Dot centres with sub-pixel accuracy, corrected for perspective and lens distortion.

The picture of a round dot is not a circle centred on the projection of the dot's centre:
under perspective (and lens distortion) the side of the dot nearer the camera is drawn
larger, so the centroid of the dot's picture lies off the projected centre, by up to a pixel
for large dots on a tilted slide. Each dot's centre is found in two steps:

1. **Centroid of the normalised signal.** Around each dot the background is a plane fitted to
   an annulus halfway between the dot and its neighbours (uneven illumination); the signal is
   the pixel's relative departure from that plane (dark dots on a light print:
   ``1 - I / background``, which a multiplicative illumination leaves unchanged; light dots
   on dark glass: ``I - background``). Its centroid over a window that follows the local
   lattice (the image of a circle halfway to the neighbours, through the local homography)
   is the centroid of the dot's picture: a symmetric blur and the pixels' own box filter
   leave a centroid where it is, and JPEG's blocks add noise, not bias. No threshold: every
   grey level counts.
2. **Bias from the local homography.** The homography from the lattice to the image is fitted
   to the dot and its neighbours (up to two steps away), so it holds the local perspective and
   the local lens distortion; the centroid of the image of the dot (a disc, or a ring for a
   hollow marker) under that homography, minus the image of its centre, is the bias, which
   is taken off. Dots, windows and homographies are recomputed from the corrected centres
   (twice). What the homography leaves out is the curvature of the lens distortion across
   one dot: below 0.005 px for dots up to a fifth of the image's half-width at 10 %
   distortion in the corner.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray

__all__ = ["disc_image_bias_px", "refine_dot_centres"]

#: Boundary points of a disc mapped through the homography for its picture's centroid.
_BOUNDARY = 96
#: Lattice neighbours (steps along each axis) fitted for the local homography.
_REACH = 2


def _map(H: FloatArray, g: FloatArray) -> FloatArray:
    """Homography of points (..., 2) -> (..., 2)."""
    w = g[..., 0] * H[2, 0] + g[..., 1] * H[2, 1] + H[2, 2]
    x = (g[..., 0] * H[0, 0] + g[..., 1] * H[0, 1] + H[0, 2]) / w
    y = (g[..., 0] * H[1, 0] + g[..., 1] * H[1, 1] + H[1, 2]) / w
    return np.stack([x, y], axis=-1)


def _polygon_area_centroid(v: FloatArray) -> tuple[float, FloatArray]:
    """Signed area and area centroid of a closed polygon (n, 2)."""
    a, b = v, np.roll(v, -1, axis=0)
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    area = 0.5 * float(cross.sum())
    centroid = ((a + b) * cross[:, None]).sum(axis=0) / (6.0 * area)
    return area, centroid


def disc_image_bias_px(
    H: FloatArray, centre: FloatArray, radius: float, hole_radius: float = 0.0
) -> FloatArray:
    """Centroid of the picture of a disc (or ring) minus the picture of its centre.

    Parameters
    ----------
    H : (3, 3) float
        Homography from the lattice (grid units) to pixels.
    centre : (2,) float
        The dot's centre, grid units.
    radius, hole_radius : float
        The dot's radius and its hole's (0: a solid dot), grid units.

    Returns
    -------
    (2,) float, px
    """
    t = np.linspace(0.0, 2.0 * np.pi, _BOUNDARY, endpoint=False)
    circle = np.column_stack([np.cos(t), np.sin(t)])
    c = np.asarray(centre, dtype=np.float64)
    area, cen = _polygon_area_centroid(_map(H, c + radius * circle))
    if hole_radius > 0:
        a_in, c_in = _polygon_area_centroid(_map(H, c + hole_radius * circle))
        cen = (area * cen - a_in * c_in) / (area - a_in)
    out: FloatArray = cen - _map(H, c)
    return out


def _local_homographies(ij: NDArray[np.intp], q: FloatArray) -> list[FloatArray | None]:
    """Per dot, the homography lattice -> pixels fitted to it and its near neighbours."""
    index = {(int(a), int(b)): k for k, (a, b) in enumerate(ij)}
    out: list[FloatArray | None] = []
    steps = range(-_REACH, _REACH + 1)
    for a, b in ij:
        near = [index[(a + da, b + db)] for da in steps for db in steps
                if (a + da, b + db) in index]  # fmt: skip
        if len(near) < 6:
            out.append(None)
            continue
        src = ij[near].astype(np.float64)
        if np.linalg.matrix_rank(src - src.mean(axis=0)) < 2:
            out.append(None)
            continue
        H, _ = cv2.findHomography(src, q[near], 0)
        out.append(None if H is None else np.asarray(H, dtype=np.float64))
    return out


def refine_dot_centres(
    gray: NDArray[np.float32],
    q_px: FloatArray,
    ij: NDArray[np.intp],
    radius: float,
    *,
    dark: bool,
    hole_radius: FloatArray | None = None,
    iterations: int = 3,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Sub-pixel dot centres, corrected for the perspective of each dot's picture.

    Parameters
    ----------
    gray : (H, W) float32
    q_px : (N, 2) float
        Rough centres (a few tenths of a pitch at worst), px.
    ij : (N, 2) int
        Each dot's lattice position (column, row; any origin, distinct).
    radius : float
        The dots' radius, in pitches.
    dark : bool
        Dark dots on a light ground (else light dots on a dark one).
    hole_radius : (N,) float, optional
        A hollow dot's hole radius in pitches (0 for solid dots).
    iterations : int

    Returns
    -------
    q_px : (N, 2) float
        Refined centres (the rough ones where ``ok`` is False).
    ok : (N,) bool
        Refined: the window inside the image, enough neighbours for the local homography.
    """
    q = np.asarray(q_px, dtype=np.float64).copy()
    n = len(q)
    holes = np.zeros(n) if hole_radius is None else np.asarray(hole_radius, dtype=np.float64)
    ok = np.zeros(n, dtype=bool)
    h_img, w_img = gray.shape
    r_win = radius + 0.5 * (0.5 - radius)  # halfway from the dot's edge to the midpoint
    r_out = 1.0 - r_win  # the annulus is symmetric about the midpoint to the neighbours
    t = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    ring = np.column_stack([np.cos(t), np.sin(t)])
    for _ in range(iterations):
        homographies = _local_homographies(ij, q)
        new = q.copy()
        ok[:] = False
        for k, H in enumerate(homographies):
            if H is None:
                continue
            g0: FloatArray = np.asarray(ij[k], dtype=np.float64)
            outline = _map(H, g0 + r_out * ring)
            x0, y0 = np.floor(outline.min(axis=0)).astype(int)
            x1, y1 = np.ceil(outline.max(axis=0)).astype(int) + 1
            if x0 < 0 or y0 < 0 or x1 > w_img or y1 > h_img:
                continue
            Hinv: FloatArray = np.asarray(np.linalg.inv(H), dtype=np.float64)
            ys, xs = np.mgrid[y0:y1, x0:x1]
            pix = np.stack([xs, ys], axis=-1).astype(np.float64)
            d = np.linalg.norm(_map(Hinv, pix) - g0, axis=-1)
            patch = gray[y0:y1, x0:x1].astype(np.float64)
            ann = (d > r_win) & (d < r_out)
            inside = d <= r_win
            if np.count_nonzero(ann) < 12 or np.count_nonzero(inside) < 5:
                continue
            A = np.column_stack([np.ones(np.count_nonzero(ann)), xs[ann] - q[k, 0],
                                 ys[ann] - q[k, 1]])  # fmt: skip
            coef = np.linalg.solve(A.T @ A, A.T @ patch[ann])  # the ground's plane
            bg = coef[0] + coef[1] * (xs[inside] - q[k, 0]) + coef[2] * (ys[inside] - q[k, 1])
            if dark:
                if np.any(bg <= 0):
                    continue
                s = 1.0 - patch[inside] / bg
            else:
                s = patch[inside] - bg
            total = float(s.sum())
            if total <= 0:
                continue
            m = np.array([(s * xs[inside]).sum(), (s * ys[inside]).sum()]) / total
            bias = disc_image_bias_px(H, g0, radius, float(holes[k]))
            new[k] = m - bias
            ok[k] = True
        q = new
    return q, ok
