"""Sub-pixel chessboard corners: windows that follow the local spacing, chosen per board by the
corners' own scatter, and a symmetry fit.

A chessboard corner is where two edges cross; around it, the picture is point-symmetric:
the grey level at ``c + d`` equals that at ``c - d`` for every small offset ``d``, whatever
the angle between the edges (perspective) and however blurred, as long as the blur is the
same on both sides. :func:`refine_corners` finds each corner in two steps:

1. OpenCV's ``cornerSubPix`` (gradients orthogonal to the offsets), with a half-window of a
   fraction of the corner's own spacing to its nearest neighbour in the grid (at most
   :data:`MAX_HALF_PX`), so a corner seen small under perspective gets a small window and one
   seen large a large one, and no window reaches a neighbouring corner or the board's edge;
2. the centre ``c`` that minimises ``sum_d w(d) (I(c + d) - I(c - d))^2`` over the same
   window (Gaussian weights), by Gauss-Newton on bilinearly sampled grey levels, all corners
   at once. It uses every grey level of the window, not only the edges' gradients.

Which fraction is best depends on the picture: a large window averages more noise and JPEG
blocks away, but reaches into what is not point-symmetric about the corner (codes or dots
printed in the squares, a lens's curvature of the edges, uneven light). No one fraction
suits every camera, so each board is refined with the fractions of :data:`WINDOW_FRACTIONS`
from the largest down (until two in a row do worse than the best) and the one whose corners
scatter least about a smooth lattice is kept (:func:`lattice_scatter_px`: a polynomial of
the grid coordinates, which follows perspective and lens distortion over the board but not
the corners' own errors). The
scatter is what a calibration's reprojection error is made of, so the choice is made on
the figure that matters, from the image itself: its squares' size, blur, noise and
compression, and whatever is printed in the squares.

A corner whose symmetry fit does not converge, or moves more than :data:`MAX_SHIFT_PX`
from step 1, keeps step 1's position. Figures on rendered and real sets: docs/vision.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray

__all__ = [
    "MAX_HALF_PX",
    "MAX_SHIFT_PX",
    "MIN_CORNERS_TO_CHOOSE",
    "SCATTER_TOLERANCE",
    "STRAY_FRACTION",
    "WINDOW_FRACTION",
    "WINDOW_FRACTIONS",
    "CornerRefinement",
    "grid_spacing_px",
    "lattice_scatter_px",
    "local_spacing_px",
    "refine_corners",
    "refine_grid_corners",
]

#: The half-window fractions (of each corner's spacing to its nearest grid neighbour) a board
#: is refined with; the one whose corners scatter least about a smooth lattice is kept.
WINDOW_FRACTIONS = (0.1, 0.13, 0.16, 0.2, 0.25, 0.32, 0.4, 0.5)
#: The fraction used where the corners are too few to judge their scatter.
WINDOW_FRACTION = 0.4
#: Boards with fewer corners keep the usual window: a lattice through a dozen corners has too
#: little freedom left for its scatter to tell the windows apart (its own misfit under
#: perspective and a strong lens dominates).
MIN_CORNERS_TO_CHOOSE = 20
#: A rough corner farther than this share of its spacing from the lattice through the others
#: starts from the lattice (boards of :data:`MIN_CORNERS_TO_CHOOSE` corners or more).
STRAY_FRACTION = 0.2
#: Another fraction replaces :data:`WINDOW_FRACTION` only where its corners scatter less by
#: more than this share (with few corners under a strong lens, the lattice's own misfit can
#: dominate the scatter, which then cannot tell the windows apart).
SCATTER_TOLERANCE = 0.03
#: The symmetry fit may move a corner at most this far from the gradient estimate, px.
MAX_SHIFT_PX = 1.0
_MIN_HALF_PX = 2
#: Half-windows are capped here: squares of hundreds of pixels gain nothing from more, and the
#: symmetry fit samples (2 h + 1)^2 / 2 offsets per corner.
MAX_HALF_PX = 20
_ITERATIONS = 10
_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
#: The smooth lattice's polynomial degree at most (cubic: perspective and a wide-angle lens's
#: barrel over a board, to well under the corners' scatter).
_LATTICE_DEGREE = 3
#: The fractions are tried from the largest down, until this many in a row scatter more than
#: the best so far (the scatter falls as the window shrinks until nothing that is not
#: point-symmetric about a corner is left in it, then rises as less of the picture is used;
#: from the largest down, since a window smaller than the blur or than the rough corners'
#: error can stay where it starts).
_STOP_AFTER = 2
#: The lattice fit keeps at least this share of its 2 N coordinates as residual freedom.
_MIN_FREEDOM = 0.4


def grid_spacing_px(corners_px: FloatArray, grid_ij: FloatArray) -> FloatArray:
    """Distance from each corner to its nearest neighbour along the grid's rows and columns.

    Parameters
    ----------
    corners_px : (N, 2) float
        Corners, any subset of a grid.
    grid_ij : (N, 2) int or float
        Each corner's column and row in the grid.

    Returns
    -------
    spacing_px : (N,) float
        ``inf`` for a corner without a neighbour among the others.
    """
    q = np.asarray(corners_px, dtype=np.float64)
    out: FloatArray = np.full(len(q), np.inf)
    if len(q) == 0:
        return out
    ij = np.rint(np.asarray(grid_ij)).astype(np.int64)
    ij = ij - ij.min(axis=0) + 1  # a free border round the grid
    slot = np.full(tuple(ij.max(axis=0) + 2), -1, dtype=np.int64)
    slot[ij[:, 0], ij[:, 1]] = np.arange(len(q))
    for da, db in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        n = slot[ij[:, 0] + da, ij[:, 1] + db]
        has = n >= 0
        d = np.full(len(q), np.inf)
        d[has] = np.linalg.norm(q[n[has]] - q[has], axis=1)
        out = np.minimum(out, d)
    return out


def local_spacing_px(corners_px: FloatArray, cols: int, rows: int) -> FloatArray:
    """Distance from each corner to its nearest neighbour along the grid's rows and columns.

    Parameters
    ----------
    corners_px : (rows * cols, 2) float
        Corners row by row.

    Returns
    -------
    spacing_px : (rows * cols,) float
    """
    grid = np.asarray(corners_px, dtype=np.float64).reshape(rows, cols, 2)
    s = np.full((rows, cols), np.inf)
    if cols > 1:
        dx = np.linalg.norm(np.diff(grid, axis=1), axis=2)
        s[:, :-1] = np.minimum(s[:, :-1], dx)
        s[:, 1:] = np.minimum(s[:, 1:], dx)
    if rows > 1:
        dy = np.linalg.norm(np.diff(grid, axis=0), axis=2)
        s[:-1, :] = np.minimum(s[:-1, :], dy)
        s[1:, :] = np.minimum(s[1:, :], dy)
    out: FloatArray = s.ravel()
    return out


def _lattice_design(grid_ij: FloatArray) -> NDArray[np.float64] | None:
    """Monomials of the grid coordinates for the smooth lattice, or None if too few corners.

    The degree is the highest (at most :data:`_LATTICE_DEGREE`, and per axis below the
    number of distinct rows or columns) that leaves :data:`_MIN_FREEDOM` of the coordinates
    as residual freedom.
    """
    ij = np.asarray(grid_ij, dtype=np.float64)
    n = len(ij)
    span = max(float(np.ptp(ij, axis=0).max()), 1.0) if n else 1.0
    u = (ij - ij.mean(axis=0)) / span if n else ij
    n_i, n_j = (len(np.unique(ij[:, k])) for k in (0, 1))
    for degree in range(_LATTICE_DEGREE, 0, -1):
        powers = [(a, b) for a in range(min(degree, n_i - 1) + 1)
                  for b in range(min(degree, n_j - 1) + 1) if a + b <= degree]  # fmt: skip
        if n - len(powers) >= _MIN_FREEDOM * n and len(powers) >= 3:
            A: NDArray[np.float64] = np.column_stack([u[:, 0] ** a * u[:, 1] ** b
                                                      for a, b in powers])  # fmt: skip
            return A
    return None


def lattice_scatter_px(corners_px: FloatArray, grid_ij: FloatArray) -> float:
    """RMS scatter of corners about a smooth lattice through them, px per coordinate.

    A polynomial of each corner's grid coordinates (degree up to 3, fewer with few corners)
    is fitted to its pixel positions; the residuals' RMS, divided by the remaining degrees of
    freedom, estimates the corners' own error: perspective and lens distortion vary slowly
    over the board and go into the fit.

    Parameters
    ----------
    corners_px : (N, 2) float
    grid_ij : (N, 2) int or float
        Each corner's column and row in the grid.

    Returns
    -------
    float
        NaN when the corners are too few for a fit with freedom to spare.
    """
    A = _lattice_design(grid_ij)
    if A is None:
        return float("nan")
    q = np.asarray(corners_px, dtype=np.float64)
    coef, _, rank, _ = np.linalg.lstsq(A, q, rcond=None)
    r = q - A @ coef
    return float(np.sqrt(np.sum(r**2) / (2.0 * max(len(q) - int(rank), 1))))


def _sample(image: NDArray[np.float32], points: FloatArray) -> FloatArray:
    """Bilinear grey levels at points (..., 2); the border repeated outside.

    ``image`` (H, W) or (H, W, C): the result is (...) or (..., C), each channel as a
    one-channel image of it would give.
    """
    p = points.astype(np.float32)
    out: FloatArray = cv2.remap(
        image, p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
    ).astype(np.float64)
    return out


def _gradient_step(gray: NDArray[np.float32], corners: FloatArray, half: FloatArray) -> FloatArray:
    """Step 1: cornerSubPix with each corner's own window."""
    out = corners.astype(np.float32).copy()
    sizes = np.maximum(_MIN_HALF_PX, np.rint(half)).astype(int)
    for h in np.unique(sizes):
        pick = sizes == h
        refined = cv2.cornerSubPix(
            gray, out[pick].reshape(-1, 1, 2).copy(), (int(h), int(h)), (-1, -1), _CRITERIA
        )
        out[pick] = np.asarray(refined).reshape(-1, 2)
    return out.astype(np.float64)


def _symmetry_levels(gray: NDArray[np.float32]) -> NDArray[np.float32]:
    """The grey levels and both gradients as one three-channel image (H, W, 3)."""
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=1) * 0.5
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=1) * 0.5
    levels: NDArray[np.float32] = cv2.merge([gray, gx, gy])
    return levels


def _symmetry_step(
    gray: NDArray[np.float32],
    start: FloatArray,
    half: FloatArray,
    levels: NDArray[np.float32] | None = None,
) -> FloatArray:
    """Step 2: the centre of point symmetry in each corner's window (Gauss-Newton).

    The grey levels and both gradients are sampled together (one three-channel image), and
    a corner that has converged is no longer iterated (its sums do not depend on the others').
    """
    half = np.maximum(half, float(_MIN_HALF_PX))
    reach = int(np.ceil(half.max()))
    oy, ox = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    d = np.column_stack([ox.ravel(), oy.ravel()]).astype(np.float64)
    d = d[(d[:, 1] > 0) | ((d[:, 1] == 0) & (d[:, 0] > 0))]  # one of each pair (d, -d)
    r2 = np.sum(d**2, axis=1)
    sigma = half[:, None] / 1.5
    w_all = np.exp(-r2[None, :] / (2.0 * sigma**2)) * (r2[None, :] <= half[:, None] ** 2)
    if levels is None:
        levels = _symmetry_levels(gray)  # (H, W, 3): grey level, d/dx, d/dy
    c = start.copy()
    converged = np.zeros(len(c), dtype=bool)
    m = len(d)
    for _ in range(_ITERATIONS):
        todo = np.flatnonzero(~converged)
        w = w_all[todo]
        centre = c[todo, None, :]
        at = _sample(levels, np.concatenate([centre + d[None], centre - d[None]], axis=1))
        diff = at[:, :m] - at[:, m:]  # (corners, offsets, 3): I(c + d) - I(c - d), and d/dx, d/dy
        r, jx, jy = diff[..., 0], diff[..., 1], diff[..., 2]
        wjx, wjy = w * jx, w * jy
        terms = np.empty((5, *w.shape))
        np.multiply(wjx, jx, out=terms[0])
        np.multiply(wjx, jy, out=terms[1])
        np.multiply(wjy, jy, out=terms[2])
        np.multiply(wjx, r, out=terms[3])
        np.multiply(wjy, r, out=terms[4])
        a11, a12, a22, b1, b2 = terms.sum(axis=2)
        det = a11 * a22 - a12**2
        with np.errstate(divide="ignore", invalid="ignore"):
            step = -np.column_stack([a22 * b1 - a12 * b2, a11 * b2 - a12 * b1]) / det[:, None]
        step[~np.isfinite(step)] = 0.0
        step = np.clip(step, -0.5, 0.5)
        c[todo] += step
        converged[todo] = np.abs(step).max(axis=1) < 1e-4
        if converged.all():
            break
    moved = np.linalg.norm(c - start, axis=1)
    keep = converged & np.all(np.isfinite(c), axis=1) & (moved <= MAX_SHIFT_PX)
    return np.where(keep[:, None], c, start)


@dataclass(frozen=True)
class CornerRefinement:
    """Refined corners of one board and how their window was chosen.

    Attributes
    ----------
    corners_px : (N, 2) float
    window_fraction : float
        The half-window as a fraction of each corner's spacing to its nearest neighbour.
    scatter_px : float
        The corners' RMS scatter about a smooth lattice (:func:`lattice_scatter_px`) with
        that window (NaN when the corners are too few to judge).
    """

    corners_px: FloatArray
    window_fraction: float
    scatter_px: float


def _half_windows(q: FloatArray, ij: FloatArray, fraction: float) -> FloatArray:
    """Each corner's half-window, px: ``fraction`` of its spacing (a corner without a grid
    neighbour among those found: of the others' median spacing)."""
    spacing = grid_spacing_px(q, ij)
    finite = np.isfinite(spacing)
    fill = float(np.median(spacing[finite])) if finite.any() else _MIN_HALF_PX / fraction
    spacing[~finite] = fill
    half: FloatArray = np.minimum(fraction * spacing, MAX_HALF_PX)
    return half


def _refine_with(
    gray: NDArray[np.float32],
    q: FloatArray,
    ij: FloatArray,
    fraction: float,
    levels: NDArray[np.float32] | None = None,
    spacing_px: FloatArray | None = None,
) -> FloatArray:
    if spacing_px is not None:  # the lattice's spacing, whatever a stray corner's
        half = np.minimum(fraction * spacing_px, MAX_HALF_PX)
        first = _gradient_step(gray, q, half)
        return _symmetry_step(gray, first, half, levels)
    first = _gradient_step(gray, q, _half_windows(q, ij, fraction))
    return _symmetry_step(gray, first, _half_windows(first, ij, fraction), levels)


def _lattice_start(q: FloatArray, ij: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rough corners with strays put back on the lattice, and each corner's spacing, px.

    A finder's rough corner can be several pixels off (blur, compression, small squares),
    and then so is its spacing to its neighbours, and a window sized by it may not reach the
    corner. A homography of the grid (RANSAC, robust to such strays) gives every corner's
    spacing, and a rough corner more than :data:`STRAY_FRACTION` of it from the homography
    starts from the homography's position instead.
    """
    spacing = grid_spacing_px(q, ij)
    finite = np.isfinite(spacing)
    square = float(np.median(spacing[finite])) if finite.any() else 0.0
    H: Any = None
    if square > 0:
        H = cv2.findHomography(ij, q, cv2.RANSAC, 0.1 * square)[0]
    if H is None:
        return q, _fill(spacing)
    lattice = cv2.perspectiveTransform(ij.reshape(-1, 1, 2), H).reshape(-1, 2)
    lattice_spacing = _fill(grid_spacing_px(lattice, ij))
    stray = np.linalg.norm(q - lattice, axis=1) > STRAY_FRACTION * lattice_spacing
    return np.where(stray[:, None], lattice, q), lattice_spacing


def _fill(spacing: FloatArray) -> FloatArray:
    """Spacings with a lone corner's (inf) replaced by the others' median."""
    out = spacing.copy()
    finite = np.isfinite(out)
    out[~finite] = float(np.median(out[finite])) if finite.any() else _MIN_HALF_PX / 0.1
    return out


def refine_grid_corners(
    gray: NDArray[np.float32],
    corners_px: FloatArray,
    grid_ij: FloatArray,
    *,
    fractions: tuple[float, ...] = WINDOW_FRACTIONS,
) -> CornerRefinement:
    """Sub-pixel corners of one board, the window chosen by the corners' scatter.

    Parameters
    ----------
    gray : (H, W) float32
        The image, grey.
    corners_px : (N, 2) float
        Rough corners (a detector's output, within a pixel or two); any subset of a grid.
    grid_ij : (N, 2) int or float
        Each corner's column and row in the grid.
    fractions : tuple of float
        Half-window fractions of the local spacing to try (:data:`WINDOW_FRACTIONS`); the
        largest of them up to :data:`WINDOW_FRACTION` is kept unless another scatters less
        by :data:`SCATTER_TOLERANCE`, or when the corners are too few to judge (fewer than
        :data:`MIN_CORNERS_TO_CHOOSE`).

    Returns
    -------
    CornerRefinement
    """
    q = np.asarray(corners_px, dtype=np.float64)
    ij = np.asarray(grid_ij, dtype=np.float64)
    if len(q) == 0:
        return CornerRefinement(q.reshape(0, 2), WINDOW_FRACTION, float("nan"))
    if len(q) < MIN_CORNERS_TO_CHOOSE or _lattice_design(ij) is None or len(fractions) == 1:
        f = fractions[0] if len(fractions) == 1 else min(WINDOW_FRACTION, max(fractions))
        out = _refine_with(gray, q, ij, f)
        return CornerRefinement(out, f, lattice_scatter_px(out, ij))
    levels = _symmetry_levels(gray)
    q, spacing = _lattice_start(q, ij)
    usual = min(WINDOW_FRACTION, max(fractions))
    out = _refine_with(gray, q, ij, usual, levels, spacing)
    default = CornerRefinement(out, usual, lattice_scatter_px(out, ij))
    best = default
    worse = 0
    for f in sorted(fractions, reverse=True):
        if f == usual:
            continue
        out = _refine_with(gray, q, ij, f, levels, spacing)
        found = CornerRefinement(out, f, lattice_scatter_px(out, ij))
        if found.scatter_px < best.scatter_px:
            best, worse = found, 0
        else:
            worse += 1
            if worse == _STOP_AFTER:
                break
    if not best.scatter_px < (1.0 - SCATTER_TOLERANCE) * default.scatter_px:
        return default  # where the scatter cannot tell, the window that suits most boards
    return best


def refine_corners(
    gray: NDArray[np.float32],
    corners_px: FloatArray,
    cols: int,
    rows: int,
    *,
    fractions: tuple[float, ...] = WINDOW_FRACTIONS,
) -> FloatArray:
    """Sub-pixel positions of a chessboard's inner corners (:func:`refine_grid_corners`).

    Parameters
    ----------
    gray : (H, W) float32
        The image, grey.
    corners_px : (rows * cols, 2) float
        Rough corners row by row (a detector's output, within a pixel or two).
    cols, rows : int
        The grid's inner corners per row and per column.
    fractions : tuple of float
        Half-window fractions to choose from (:data:`WINDOW_FRACTIONS`).

    Returns
    -------
    corners_px : (rows * cols, 2) float
    """
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    ij = np.column_stack([j.ravel(), i.ravel()]).astype(np.float64)
    return refine_grid_corners(gray, corners_px, ij, fractions=fractions).corners_px
