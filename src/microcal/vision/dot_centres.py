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
    r_win = radius + 0.5 * (0.5 - radius)  # halfway from the dot's edge to the midpoint
    r_out = 1.0 - r_win  # the annulus is symmetric about the midpoint to the neighbours
    for _ in range(iterations):
        homographies = _local_homographies(ij, q)
        have = np.array([H is not None for H in homographies], dtype=bool)
        new = q.copy()
        ok[:] = False
        if not np.any(have):
            break
        idx = np.flatnonzero(have)
        Hs: FloatArray = np.stack([H for H in homographies if H is not None])  # (M, 3, 3)
        g0 = ij[idx].astype(np.float64)
        centroid, good = _centroids(gray, Hs, g0, q[idx], r_win, r_out, dark)
        bias = _biases(Hs, g0, radius, holes[idx])
        new[idx[good]] = centroid[good] - bias[good]
        ok[idx[good]] = True
        q = new
    return q, ok


#: Pixels gathered at once (dots x window), to bound the memory of the vectorised windows.
_CHUNK_PX = 300_000


def _map_batch(H: FloatArray, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Homographies (M, 3, 3) of points x, y (M, ...) -> u, v (M, ...)."""
    shape = (len(H),) + (1,) * (x.ndim - 1)
    h = [[H[:, a, b].reshape(shape) for b in range(3)] for a in range(3)]
    w = h[2][0] * x + h[2][1] * y + h[2][2]
    return (h[0][0] * x + h[0][1] * y + h[0][2]) / w, (h[1][0] * x + h[1][1] * y + h[1][2]) / w


def _biases(Hs: FloatArray, g0: FloatArray, radius: float, holes: FloatArray) -> FloatArray:
    """:func:`disc_image_bias_px` of many dots at once, (M, 2)."""
    t = np.linspace(0.0, 2.0 * np.pi, _BOUNDARY, endpoint=False)

    def area_centroid(r: FloatArray) -> tuple[FloatArray, FloatArray]:
        x = g0[:, :1] + r[:, None] * np.cos(t)
        y = g0[:, 1:] + r[:, None] * np.sin(t)
        u, v = _map_batch(Hs, x, y)
        u2, v2 = np.roll(u, -1, axis=1), np.roll(v, -1, axis=1)
        cross = u * v2 - v * u2
        area = 0.5 * cross.sum(axis=1)
        safe = np.where(area == 0, 1.0, area)
        cen = np.stack([((u + u2) * cross).sum(axis=1), ((v + v2) * cross).sum(axis=1)], axis=1)
        return area, cen / (6.0 * safe[:, None])

    a_out, c_out = area_centroid(np.full(len(g0), radius))
    cen = c_out
    hollow = holes > 0
    if np.any(hollow):
        a_in, c_in = area_centroid(np.where(hollow, holes, 0.5 * radius))
        ring = (a_out[:, None] * c_out - a_in[:, None] * c_in) / (a_out - a_in)[:, None]
        cen = np.where(hollow[:, None], ring, c_out)
    u0, v0 = _map_batch(Hs, g0[:, 0], g0[:, 1])
    out: FloatArray = cen - np.column_stack([u0, v0])
    return out


def _centroids(
    gray: NDArray[np.float32],
    Hs: FloatArray,
    g0: FloatArray,
    q: FloatArray,
    r_win: float,
    r_out: float,
    dark: bool,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Centroids of the normalised signal in each dot's window, (M, 2), and which are valid."""
    m = len(Hs)
    t = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    ox, oy = _map_batch(Hs, g0[:, :1] + r_out * np.cos(t), g0[:, 1:] + r_out * np.sin(t))
    x0 = np.floor(ox.min(axis=1)).astype(int)
    y0 = np.floor(oy.min(axis=1)).astype(int)
    x1 = np.ceil(ox.max(axis=1)).astype(int) + 1
    y1 = np.ceil(oy.max(axis=1)).astype(int) + 1
    h_img, w_img = gray.shape
    good = (x0 >= 0) & (y0 >= 0) & (x1 <= w_img) & (y1 <= h_img) & np.isfinite(ox).all(axis=1)
    out = np.full((m, 2), np.nan)
    if not np.any(good):
        return out, good
    side = int(max(np.max((x1 - x0)[good]), np.max((y1 - y0)[good])))
    grid = np.arange(side, dtype=np.float64)
    valid = np.flatnonzero(good)
    per_chunk = max(1, _CHUNK_PX // (side * side))
    for start in range(0, len(valid), per_chunk):
        k = valid[start : start + per_chunk]
        xs = np.minimum(x0[k, None, None] + grid[None, None, :], w_img - 1)
        ys = np.minimum(y0[k, None, None] + grid[None, :, None], h_img - 1)
        xs, ys = np.broadcast_arrays(xs, ys)
        Hinv: FloatArray = np.asarray(np.linalg.inv(Hs[k]), dtype=np.float64)
        u, v = _map_batch(Hinv, xs, ys)
        d = np.hypot(u - g0[k, 0, None, None], v - g0[k, 1, None, None])
        inside_box = (xs < x1[k, None, None]) & (ys < y1[k, None, None])
        patch = gray[ys.astype(np.intp), xs.astype(np.intp)].astype(np.float64)
        ann = (d > r_win) & (d < r_out) & inside_box
        inside = (d <= r_win) & inside_box
        dx = xs - q[k, 0, None, None]
        dy = ys - q[k, 1, None, None]
        w = ann.astype(np.float64)
        # the ground's plane a + b dx + c dy fitted to the annulus (normal equations)
        wx, wy = w * dx, w * dy

        def dot(a: FloatArray, b: FloatArray) -> FloatArray:
            out: FloatArray = np.einsum("kij,kij->k", a, b)
            return out

        s1, sx, sy = w.sum(axis=(1, 2)), wx.sum(axis=(1, 2)), wy.sum(axis=(1, 2))
        sxx, sxy, syy = dot(wx, dx), dot(wx, dy), dot(wy, dy)
        si, sxi, syi = dot(w, patch), dot(wx, patch), dot(wy, patch)
        A = np.stack([np.stack([s1, sx, sy], -1), np.stack([sx, sxx, sxy], -1),
                      np.stack([sy, sxy, syy], -1)], axis=1)  # fmt: skip
        enough = (ann.sum(axis=(1, 2)) >= 12) & (inside.sum(axis=(1, 2)) >= 5)
        A[~enough] = np.eye(3)
        coef = np.linalg.solve(A, np.stack([si, sxi, syi], -1)[..., None])[..., 0]
        ground = coef[:, 0, None, None] + coef[:, 1, None, None] * dx + coef[:, 2, None, None] * dy
        if dark:
            positive = np.all(np.where(inside, ground, 1.0) > 0, axis=(1, 2))
            signal = np.where(inside, 1.0 - patch / np.where(ground > 0, ground, 1.0), 0.0)
        else:
            positive = np.ones(len(k), dtype=bool)
            signal = np.where(inside, patch - ground, 0.0)
        total = signal.sum(axis=(1, 2))
        fine = enough & positive & (total > 0)
        safe = np.where(fine, total, 1.0)
        out[k, 0] = dot(signal, xs) / safe
        out[k, 1] = dot(signal, ys) / safe
        good[k] &= fine
    return out, good
