"""Chessboards of which any part is in view, numbered from three marker circles.

A chessboard larger than the field (a calibration slide under a microscope) cannot be
numbered from its own corner. Three circles printed inside squares (dark in light squares,
light in dark ones, an L of neighbouring squares; the target spec's ``markers=``) fix the
numbering instead:

1. **Corners.** OpenCV's sector-based finder (``findChessboardCornersSB`` with
   ``CALIB_CB_LARGER | CALIB_CB_MARKER``) returns every corner of the visible part of the
   board and, for each square, whether it holds a circle and of which colour.
2. **Numbering.** Of the eight ways the found grid can lie on the board (four turns, either
   hand), those that put the circles found on the spec's marker squares with the right
   colours are kept; of the two an L allows, the one that shows the board from the front
   (not mirrored) is taken. Each corner's place on the board follows; corners within half
   a square of the image's edge are left out.
3. **Corners refined** as any chessboard's
   (:func:`~microcal.vision.corner_refinement.refine_grid_corners`), then by the model of
   two blurred edges fitted to the pixels (:mod:`~microcal.vision.corner_model`): a slide
   under a microscope is sharp, where interpolating between pixels draws the corners by up
   to 0.025 px towards or away from the pixel lattice.

Where the finder sees the board but not its circles, or the circles contradict the spec
(the colours of the marker squares differ), the view is not numbered and the detection says
why.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from .corner_model import fit_corner_model
from .corner_refinement import refine_grid_corners
from .detection import Detection, homography_rms_px
from .targets import Target, marker_text

__all__ = ["MISMATCH_PREFIX", "detect_marker_chessboard"]

MISMATCH_PREFIX = "the marker circles seen do not match the spec's markers"
#: The smallest part of a board the finder is asked for (inner corners); it may find more.
MIN_PART = (3, 3)
#: The seed of OpenCV's random generator before each search (as for whole chessboards).
SEED = 0x6D63
#: Neighbouring corners of a board found are this share of the median spacing apart, at most
#: more or less (perspective over a part of a board in one view stays well within it).
MAX_STEP_CHANGE = 0.5
#: OpenCV's meta values: the square below-right of a corner holds a light circle in a dark
#: square (3) or a dark circle in a light square (4).
_LIGHT_IN_DARK, _DARK_IN_LIGHT = 3, 4

_WAYS = [np.array(m) for m in (
    ((1, 0), (0, 1)), ((0, -1), (1, 0)), ((-1, 0), (0, -1)), ((0, 1), (-1, 0)),
    ((1, 0), (0, -1)), ((0, 1), (1, 0)), ((-1, 0), (0, 1)), ((0, -1), (-1, 0)),
)]  # fmt: skip


def _find(img8: NDArray[np.uint8], flags: int) -> tuple[FloatArray, NDArray[np.uint8]] | None:
    cv2.setRNGSeed(SEED)
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(img8, MIN_PART, flags)
    if not found or corners is None or meta is None:
        return None
    meta = np.asarray(meta, dtype=np.uint8)
    grid = np.asarray(corners, dtype=np.float64).reshape(*meta.shape, 2)
    steps = np.concatenate([np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel(),
                            np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel()])  # fmt: skip
    if steps.size == 0 or np.any(np.abs(steps / np.median(steps) - 1.0) > MAX_STEP_CHANGE):
        return None  # not a board's lattice (the finder now and then returns such a grid)
    return grid, meta


def _placements(
    meta: NDArray[np.uint8], target: Target
) -> list[tuple[NDArray[np.int_], NDArray[np.int_]]]:
    """The ways (S, t) that map the found grid's squares onto the board's squares (board
    square = S @ found square + t, squares as (column, row) of their top-left corner in the
    found grid, counted as the spec counts), putting each circle seen on a marker of the
    spec with its colour."""
    rows, cols = np.nonzero((meta == _LIGHT_IN_DARK) | (meta == _DARK_IN_LIGHT))
    seen = np.column_stack([cols, rows]).astype(int)
    light_in_dark = meta[rows, cols] == _LIGHT_IN_DARK
    spec = {m: (m[0] + m[1]) % 2 == 0 for m in target.markers}  # True: a dark square
    fits: list[tuple[NDArray[np.int_], NDArray[np.int_]]] = []
    if len(seen) == 0:
        return fits
    half = np.full(2, 0.5)
    for S in _WAYS:
        for m in target.markers:
            # points in square units: found corner (j, i) at (j, i), board square (c, r)
            # spanning (c, r) to (c + 1, r + 1); board point = S @ found point + u, the
            # first circle's square centre onto marker m's
            u = np.rint(np.array(m) + half - S @ (seen[0] + half)).astype(int)
            placed = [tuple(int(v) for v in np.rint(S @ (s + half) + u - half)) for s in seen]
            if all(p in spec and spec[p] == bool(d)
                   for p, d in zip(placed, light_in_dark, strict=True)):  # fmt: skip
                fits.append((S, u))
    return fits


def _front(S: NDArray[np.int_], grid: FloatArray) -> bool:
    """Whether the board, numbered by S, is seen from the front (its x and y axes turn in the
    image as the image's own)."""
    ex = np.median((grid[:, 1:] - grid[:, :-1]).reshape(-1, 2), axis=0)
    ey = np.median((grid[1:, :] - grid[:-1, :]).reshape(-1, 2), axis=0)
    inv = np.rint(np.linalg.inv(S)).astype(int)
    bx, by = inv[0, 0] * ex + inv[1, 0] * ey, inv[0, 1] * ex + inv[1, 1] * ey
    return float(bx[0] * by[1] - bx[1] * by[0]) > 0


def detect_marker_chessboard(
    gray: NDArray[np.float32], img8: NDArray[np.uint8], target: Target
) -> Detection:
    """The visible part of a chessboard, numbered from its marker circles.

    Parameters
    ----------
    gray : (H, W) float32
        The image, grey (corners are refined on it).
    img8 : (H, W) uint8
        The same, stretched to 8 bits (for OpenCV's finder).
    target : Target
        A chessboard with ``markers``.

    Returns
    -------
    Detection
        ids into ``target.points_um()`` of the inner corners seen that lie on the spec's
        board, refined; ``found=False`` with the reason where the circles are not seen or do
        not match the spec.
    """
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_LARGER | cv2.CALIB_CB_MARKER
    found = None
    chosen: list[tuple[NDArray[np.int_], NDArray[np.int_]]] = []
    # the finder on the image as it is, then upsampled (it sees small circles better, and now
    # and then a larger part of the board, or the circles' colours right)
    for extra in (0, cv2.CALIB_CB_ACCURACY):
        attempt = _find(img8, flags | extra)
        if attempt is None:
            continue
        fits = _placements(attempt[1], target)
        front = [f for f in fits if _front(f[0], attempt[0])]
        if front or fits or found is None:
            found, chosen = attempt, front or fits
        if chosen:
            break
    if found is None:
        if _find(img8, flags & ~cv2.CALIB_CB_MARKER) is not None:
            return Detection.none(
                "a chessboard is in view but not its 3 marker circles (or too little of the "
                "board around them); move the board so that its markers are"
            )
        return Detection.none("no chessboard found")
    grid, meta = found
    if not chosen:
        n = int(np.count_nonzero(meta >= _LIGHT_IN_DARK))
        return Detection.none(
            f"{MISMATCH_PREFIX} (markers={marker_text(target.markers)}): {n} circle(s) seen, "
            f"their squares' colours or layout differ from the spec's (check the markers' "
            f"squares: a marker square one off changes its colour)"
        )
    S, u = chosen[0]
    rows, cols = grid.shape[:2]
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    # the board's inner corner (c, r) is at point (c + 1, r + 1)
    board = np.stack([j.ravel(), i.ravel()], axis=1) @ S.T + u - 1
    q = grid.reshape(-1, 2)
    # the finder returns corners up to the image's edge and past it: only those with room
    # for the refinement's window (half a square) are kept
    square = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2)))
    h, w = gray.shape
    room = 0.5 * square
    in_image = (q[:, 0] >= room) & (q[:, 1] >= room) & (q[:, 0] <= w - 1 - room) & \
        (q[:, 1] <= h - 1 - room)  # fmt: skip
    inside = in_image & (board[:, 0] >= 0) & (board[:, 1] >= 0) & (board[:, 0] < target.cols) & \
        (board[:, 1] < target.rows)  # fmt: skip
    if np.count_nonzero(inside) < 4:
        return Detection.none(
            f"only {np.count_nonzero(inside)} of the {len(q)} corners seen lie on the spec's "
            f"{target.cols}x{target.rows} board; give the board's whole size"
        )
    board, q = board[inside], q[inside]
    q = refine_grid_corners(gray, q, board.astype(np.float64)).corners_px
    q = _model_corners(gray, q, board.astype(np.float64))
    ids = (board[:, 1] * target.cols + board[:, 0]).astype(np.intp)
    order = np.argsort(ids)
    ids, q = ids[order], q[order]
    left = int(np.count_nonzero(in_image)) - len(ids)
    method = "marker circles" + (f" ({left} beyond the spec's board left out)" if left else "")
    return Detection(True, ids, q, homography_rms_px(target, ids, q), method=method)


def _model_corners(gray: NDArray[np.float32], q: FloatArray, board: FloatArray) -> FloatArray:
    """Corners refined by the model of two blurred edges
    (:func:`~microcal.vision.corner_model.fit_corner_model`): sharp pictures' corners
    without the interpolation's pull towards the pixel lattice. The edges' directions come
    from the homography of the board's grid to the corners; a corner whose fit fails keeps
    the symmetry fit's position."""
    if len(q) < 4:
        return q
    H: Any = cv2.findHomography(board, q, 0)[0]
    if H is None:
        return q

    def mapped(g: FloatArray) -> FloatArray:
        out: FloatArray = cv2.perspectiveTransform(g.reshape(-1, 1, 2), H).reshape(-1, 2)
        return out

    axes = np.stack([mapped(board + (0.5, 0.0)) - mapped(board - (0.5, 0.0)),
                     mapped(board + (0.0, 0.5)) - mapped(board - (0.0, 0.5))], axis=1)  # fmt: skip
    spacing = np.linalg.norm(axes, axis=2).min(axis=1)
    return fit_corner_model(gray, q, axes, spacing)[0]
