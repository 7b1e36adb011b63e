"""Target detection in images: chessboards, dot grids, ChArUco boards.

Every detector takes an image of any usual kind (8 or 16 bit, grey or colour) and returns a
:class:`Detection`: the features found, their ids (index into ``Target.points_um()``), their
pixel positions with sub-pixel accuracy and a quality figure; or, when there is no target,
``found=False`` with the reason. An image without a target is not an error.

- Chessboard: OpenCV's classic detector, the sector-based one (``findChessboardCornersSB``)
  when the classic one fails; corners refined by :mod:`~microcal.vision.corner_refinement`
  (windows that follow each corner's spacing, then a point-symmetry fit). The corners are
  numbered from the board's origin as far as the squares' colours tell; a board that looks the
  same turned is numbered so that its first row runs most nearly towards +x in the image.
- Dot grid: dots segmented by Otsu's threshold, centres from background-subtracted
  intensity moments in a window, then indexed on the lattice (two lattice vectors from the
  neighbours, grid coordinates by rounding); works for dense grids of thousands of dots.
- Dot grid with marker dots (a slide that overfills the field): any part of the grid,
  numbered from its hollow dots (:mod:`~microcal.vision.marker_grid`), centres corrected for
  perspective (:mod:`~microcal.vision.dot_centres`).
- Chessboard followed from the frame before (``previous_px``): while a board settles it
  moves a small fraction of a square between frames, so its corners are refined from the
  corners found in the frame before instead of searched for again (a fraction of the time);
  the board is searched for as usual when they no longer fit (:func:`_track_chessboard`).
- Chessboard with marker circles (a board that overfills the field): any part of the board,
  numbered from its three circles (:mod:`~microcal.vision.chessboard_markers`), corners
  refined as a chessboard's.
- ChArUco: OpenCV's ChArUco detector; ids are OpenCV's corner ids; the corners refined as
  a chessboard's (those found, each by its own neighbours' spacing).

The quality figure is the RMS residual (px) of a homography from the target plane to the
detected features: near the detection noise for a good detection.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import InputError
from .board_symmetry import turn_ids
from .chessboard_markers import detect_marker_chessboard
from .corner_refinement import WINDOW_FRACTIONS, refine_corners, refine_grid_corners
from .detection import Detection
from .detection import homography_rms_px as _homography_rms
from .marker_grid import detect_marker_grid
from .targets import Target

__all__ = ["Detection", "detect", "to_gray"]


def to_gray(image: NDArray[np.generic]) -> NDArray[np.float32]:
    """Grey float32 image from any 2D or colour image (colour: OpenCV's BGR weights)."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img[:, :, :3].astype(np.float32), cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise InputError(f"image: expected (H, W) or (H, W, 3), got shape {img.shape}")
    return img.astype(np.float32, copy=False)


def _to_uint8(gray: NDArray[np.float32]) -> NDArray[np.uint8]:
    """Stretch to 8 bits between the 0.5 and 99.5 percentiles (for OpenCV's finders)."""
    lo, hi = np.percentile(gray, (0.5, 99.5))
    if hi <= lo:
        return np.zeros(gray.shape, dtype=np.uint8)
    out: NDArray[np.uint8] = np.clip((gray - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
    return out


def _square_levels(gray: NDArray[np.float32], grid: FloatArray) -> FloatArray:
    """Grey level at the centre of each inner square, (rows - 1, cols - 1)."""
    centres = 0.25 * (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:])
    h, w = gray.shape
    x = np.clip(np.rint(centres[..., 0]).astype(int), 0, w - 1)
    y = np.clip(np.rint(centres[..., 1]).astype(int), 0, h - 1)
    out: FloatArray = gray[y, x].astype(np.float64)
    return out


def _colour_score(gray: NDArray[np.float32], grid: FloatArray) -> float:
    """Sum of the inner squares' grey levels with alternating signs, square (0, 0) positive.

    Negative when square (0, 0), between corners 0, 1, COLS and COLS + 1, is the dark one:
    the colour convention of :mod:`microcal.vision.targets`.
    """
    levels = _square_levels(gray, grid)
    b, a = np.indices(levels.shape)
    return float(np.sum(np.where((a + b) % 2 == 0, 1.0, -1.0) * (levels - levels.mean())))


def _not_a_chessboard(gray: NDArray[np.float32], corners: FloatArray, cols: int, rows: int) -> str:
    """Why these corners do not bound a chessboard's squares ("" when they do).

    A finder may return a lattice that skips a row or reaches into the background; then some
    "squares" straddle two real ones. On a real board each square differs from its four
    neighbours the same way: the dark ones darker than the light ones next to them (a local
    test, so uneven lighting over the board does not matter).
    """
    levels = _square_levels(gray, corners.reshape(rows, cols, 2))
    if levels.size < 2:
        return ""
    b, a = np.indices(levels.shape)
    even = (a + b) % 2 == 0
    light_even = levels[even].mean() > levels[~even].mean()
    s = np.where(even == light_even, 1.0, -1.0)  # +1 on the light squares
    steps = np.concatenate(
        [((levels[:, :-1] - levels[:, 1:]) * s[:, :-1]).ravel(),
         ((levels[:-1, :] - levels[1:, :]) * s[:-1, :]).ravel()]
    )  # fmt: skip
    if np.all(steps > 0):
        return ""
    return (
        f"the {cols}x{rows} corners found do not bound alternating dark and light squares "
        "(a mis-detected or partly hidden board)"
    )


#: Squares smaller than this (px) are noise to a chessboard finder, not a board.
MIN_SQUARE_PX = 8.0
#: A board's corners lie on a homography of its lattice within this share of a square (lens
#: distortion over a board stays far below it); a lattice that skips a row does not.
MAX_LATTICE_RESIDUAL = 0.1


def _square_px(q: FloatArray, cols: int, rows: int) -> float:
    """The median distance between neighbouring corners (rows * cols, 2) of a grid, px."""
    grid = q.reshape(rows, cols, 2)
    spacing = np.concatenate([np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel(),
                              np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel()])  # fmt: skip
    return float(np.median(spacing))


def _board_edges(gray: NDArray[np.float32], q: FloatArray, cols: int, rows: int) -> str:
    """Why the corners found are not the whole board of the spec ("" when they are).

    Two rings of squares around the corners are sampled (the lattice extended by the
    homography of the corners): the first ring is the board's own border squares, which
    alternate like the inner ones (a lattice found in noise or clutter does not); past
    them a board of the spec's size ends (its margin, the background), while a larger
    board goes on alternating (a finder asked for fewer corners than the board has finds a
    part of it, numbered as if it were the whole: positions then come out squares off).
    Only cells inside the image count.
    """
    square = _square_px(q, cols, rows)
    if square < MIN_SQUARE_PX:
        return f"the corners found are {square:.1f} px apart: noise, not a board"
    j, i = np.meshgrid(np.arange(cols, dtype=np.float64), np.arange(rows, dtype=np.float64))
    lattice = np.stack([j.ravel(), i.ravel()], axis=1)
    H: Any = cv2.findHomography(lattice, q, 0)[0]
    if H is None:
        return ""
    fitted = cv2.perspectiveTransform(lattice.reshape(-1, 1, 2), H).reshape(-1, 2)
    residual = float(np.sqrt(np.mean(np.sum((fitted - q) ** 2, axis=1))))
    if residual > MAX_LATTICE_RESIDUAL * square:
        return (
            f"the {cols}x{rows} corners found are not a regular lattice (off a board's by "
            f"{residual:.1f} px RMS): a mis-detected or partly hidden board"
        )
    je, ie = np.meshgrid(np.arange(-2.0, cols + 2), np.arange(-2.0, rows + 2))
    ext = cv2.perspectiveTransform(np.stack([je.ravel(), ie.ravel()], axis=1).reshape(-1, 1, 2), H)
    grid = ext.reshape(rows + 4, cols + 4, 2)
    box = max(1, int(0.3 * square))  # a patch of each square, not a pixel
    levels = _square_levels(cv2.blur(gray, (box, box)), grid)  # (rows + 3, cols + 3)
    centres = 0.25 * (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:])
    h, w = gray.shape
    x, y = centres[..., 0], centres[..., 1]
    seen = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    b, a = np.indices(levels.shape)
    inner = levels[2:-2, 2:-2]
    parity = (a + b) % 2 == 0
    light_even = inner[parity[2:-2, 2:-2]].mean() > inner[~parity[2:-2, 2:-2]].mean()
    sign = np.where(parity == light_even, 1.0, -1.0)  # +1 where a light square would be
    along = (levels[:, :-1] - levels[:, 1:]) * sign[:, :-1]  # > 0 between alternating squares
    across = (levels[:-1, :] - levels[1:, :]) * sign[:-1, :]
    contrast = float(np.median(np.concatenate([along[2:-2, 2:-2].ravel(),
                                               across[2:-2, 2:-2].ravel()])))  # fmt: skip
    if contrast <= 0:
        return ""
    # the border squares: steps within rings 0-1 (inner plus first ring), inside the image
    ok_along = seen[1:-1, 1:-2] & seen[1:-1, 2:-1]
    ok_across = seen[1:-2, 1:-1] & seen[2:-1, 1:-1]
    border = np.concatenate([along[1:-1, 1:-1][ok_along], across[1:-1, 1:-1][ok_across]])
    if border.size and np.mean(border > 0) < 0.75:
        return (
            f"the {cols}x{rows} corners found are not bordered by a chessboard's squares "
            "(a lattice found in noise or clutter, or a partly hidden board)"
        )
    sides: dict[str, tuple[int | slice, int | slice]] = {
        "top": (0, slice(1, -1)), "bottom": (-1, slice(1, -1)),
        "left": (slice(1, -1), 0), "right": (slice(1, -1), -1),
    }  # fmt: skip
    for side, index in sides.items():
        ring, ok, s = (np.asarray(v[index]) for v in (levels, seen, sign))
        pairs = ok[:-1] & ok[1:]
        if np.count_nonzero(pairs) < 2:
            continue
        alternating = (ring[:-1] - ring[1:]) * s[:-1] > 0.5 * contrast
        if np.mean(alternating[pairs]) >= 0.8:
            return (
                f"the board goes on past its {side} edge: it has more than the spec's "
                f"{cols}x{rows} inner corners (give the target spec of the whole board)"
            )
    return ""


def _orient(gray: NDArray[np.float32], corners: FloatArray, target: Target) -> FloatArray:
    """Number the corners from the board's own origin, as far as the picture can tell.

    Of the turns that map the grid onto itself, those whose square (0, 0) has the wrong
    colour are left out (that decides an odd x even board); of the rest (the turns of
    :func:`~microcal.vision.board_symmetry.ambiguous_turns`), the one whose first row runs
    most nearly towards +x in the image is taken. Which of those is right is for the
    stereo geometry to decide (:mod:`microcal.vision.view_consistency`).
    """
    cols, rows = target.pattern_size
    best: tuple[float, FloatArray] | None = None
    for turn in (0, 90, 180, 270) if cols == rows else (0, 180):
        q = np.empty_like(corners)
        q[turn_ids(target, turn)] = corners
        grid = q.reshape(rows, cols, 2)
        if _colour_score(gray, grid) > 0:
            continue
        direction = grid[0, -1] - grid[0, 0]
        along_x = float(direction[0] / max(float(np.linalg.norm(direction)), 1e-12))
        if best is None or along_x > best[0]:
            best = (along_x, q)
    return corners if best is None else best[1]


#: The window fractions a half-resolution search refines with: its corners only place the
#: full-resolution search, so fewer candidates do.
COARSE_FRACTIONS = (0.13, 0.2, 0.32)


def _detect_chessboard(
    gray: NDArray[np.float32],
    target: Target,
    refused: list[FloatArray] | None = None,
    fractions: tuple[float, ...] = WINDOW_FRACTIONS,
) -> Detection:
    """The chessboard in ``gray``; corners found and then refused are added to ``refused``."""
    size = target.pattern_size
    img8 = _to_uint8(gray)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(img8, size, flags=flags)
    method, why = "classic", ""
    if found:
        why = _not_a_chessboard(gray, corners.reshape(-1, 2).astype(np.float64), *size)
        if why and refused is not None:
            refused.append(corners.reshape(-1, 2).astype(np.float64))
    if not found or why:
        # The sector-based finder draws from OpenCV's global random generator: seeded, the
        # same image gives the same corners whatever was detected before (or in which
        # process: measurement runs cameras in parallel)
        cv2.setRNGSeed(SECTOR_BASED_SEED)
        found, corners = cv2.findChessboardCornersSB(img8, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        method = "sector-based"
        if found:
            why = _not_a_chessboard(gray, corners.reshape(-1, 2).astype(np.float64), *size)
            if why and refused is not None:
                refused.append(corners.reshape(-1, 2).astype(np.float64))
        if not found or why:
            return Detection.none(why or f"no {size[0]}x{size[1]} chessboard found")
    q = corners.reshape(-1, 2).astype(np.float64)
    q = _orient(gray, q, target)
    q = refine_corners(gray, q, *size, fractions=fractions)
    not_whole = _board_edges(gray, q, *size)
    if not_whole:
        if refused is not None:
            refused.append(q)
        return Detection.none(not_whole)
    ids = np.arange(len(q), dtype=np.intp)
    return Detection(True, ids, q, _homography_rms(target, ids, q), method=method)


#: The seed of OpenCV's random generator before each sector-based search.
SECTOR_BASED_SEED = 0x6D63

#: Images larger than this (pixels) are first searched at half resolution.
COARSE_SEARCH_PX = 600_000


def _detect_chessboard_coarse_to_fine(gray: NDArray[np.float32], target: Target) -> Detection:
    """Search a large image at half resolution first, then refine in a full-resolution box."""
    if gray.size <= COARSE_SEARCH_PX:
        return _detect_chessboard(gray, target)
    small = cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    refused: list[FloatArray] = []
    coarse = _detect_chessboard(small, target, refused, COARSE_FRACTIONS)
    if coarse.found or refused:
        # Found, or found and refused at half resolution (a wrong spec, part of a board, or a
        # check too fine for half the pixels): decided at full resolution around those corners.
        # Searching the whole image instead takes ~20x as long (tens of seconds at 5 MP) and
        # finds the same corners.
        q = (coarse.q_px if coarse.found else refused[-1]) * 2.0 + 0.5
        square = float(np.median(np.linalg.norm(np.diff(q, axis=0), axis=1)))
        lo = np.floor(q.min(axis=0) - 3 * square).astype(int)
        hi = np.ceil(q.max(axis=0) + 3 * square).astype(int)
        h, w = gray.shape
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], w), min(hi[1], h)
        fine = _detect_chessboard(gray[y0:y1, x0:x1], target)
        if fine.found:
            return Detection(True, fine.ids, fine.q_px + np.array([x0, y0]), fine.quality_px,
                             method=fine.method + ", coarse-to-fine")  # fmt: skip
        if refused:
            return fine
    return _detect_chessboard(gray, target)


#: A board followed from the frame before may have moved this share of a square at most.
TRACK_MAX_MOVE = 0.25
#: ... and its corners moved together: each within this of their median move, px (a corner
#: refined onto something else, a glare or a shadow over it, moves apart from the others;
#: the symmetry fit's own bound, ``corner_refinement.MAX_SHIFT_PX``: two frames' noise
#: stays well inside it).
TRACK_SPREAD_PX = 1.0
#: ... and they lie on the board's plane as well as the frame before's did: their homography
#: residual at most twice that one's plus this, px.
TRACK_RESIDUAL_PX = 0.1


def _track_chessboard(gray: NDArray[np.float32], target: Target, previous: FloatArray) -> Detection:
    """The chessboard of ``target`` refined from its corners in the frame before (numbered as
    they are); ``found=False`` when they no longer fit this frame (the caller searches)."""
    cols, rows = target.pattern_size
    h, w = gray.shape
    if previous.shape != (cols * rows, 2) or not np.all(np.isfinite(previous)):
        return Detection.none("no corners of the frame before to follow")
    if np.any(previous < 2) or np.any(previous[:, 0] > w - 3) or np.any(previous[:, 1] > h - 3):
        return Detection.none("the corners of the frame before are at the region's edge")
    square = _square_px(previous, cols, rows)
    q = refine_corners(gray, previous, cols, rows)
    move = q - previous
    typical = np.median(move, axis=0)
    ids = np.arange(len(q), dtype=np.intp)
    residual = _homography_rms(target, ids, q)
    if (
        float(np.linalg.norm(typical)) > TRACK_MAX_MOVE * square
        or float(np.max(np.linalg.norm(move - typical, axis=1))) > TRACK_SPREAD_PX
        or residual > 2.0 * _homography_rms(target, ids, previous) + TRACK_RESIDUAL_PX
        or _not_a_chessboard(gray, q, cols, rows)
        # square (0, 0) the dark one, as a search numbers it: not a lattice an odd number of
        # squares off (one an even number off reaches past the board: not alternating)
        or _colour_score(gray, q.reshape(rows, cols, 2)) > 0
    ):
        return Detection.none("the board moved away from the corners of the frame before")
    return Detection(True, ids, q, residual, method="followed")


def _dot_centres(gray: NDArray[np.float32], bright: bool) -> FloatArray:
    """Centres of the dots: local maxima of the smoothed image, refined by moments.

    Local maxima (not a global threshold) separate dense, blurred dots whose valleys never
    fall back to the glass level; maxima closer than a third of the dot pitch are merged.
    """
    signal = (gray if bright else -gray).astype(np.float32)
    smooth = cv2.GaussianBlur(signal, (0, 0), 1.0)
    lo, hi = np.percentile(smooth, (5.0, 99.8))
    if hi <= lo:
        return np.zeros((0, 2))
    level = lo + 0.5 * (hi - lo)
    peaks = (smooth >= cv2.dilate(smooth, np.ones((3, 3), np.uint8))) & (smooth > level)
    ys, xs = np.nonzero(peaks)
    if len(xs) < 4:
        return np.column_stack([xs, ys]).astype(np.float64)
    from scipy.spatial import cKDTree

    pts = np.column_stack([xs, ys]).astype(np.float64)
    dist, _ = cKDTree(pts).query(pts, k=2)
    pitch = float(np.median(dist[:, 1]))
    radius = max(1, round(0.35 * pitch))
    size = 2 * radius + 1
    kernel = np.ones((size, size), np.uint8)
    prominence = smooth - cv2.erode(smooth, kernel)
    peaks &= (smooth >= cv2.dilate(smooth, kernel)) & (prominence > 0.1 * (hi - lo))
    ys, xs = np.nonzero(peaks)
    h, w = gray.shape
    half = max(2, round(0.5 * pitch))
    inside = (xs >= half) & (ys >= half) & (xs < w - half) & (ys < h - half)
    xs, ys = xs[inside], ys[inside]
    if len(xs) == 0:
        return np.zeros((0, 2))
    # Gaussian-weighted centroid in a window that follows the estimate (no pixel locking),
    # on the background-subtracted signal; all dots at once.
    oy, ox = np.mgrid[-half : half + 1, -half : half + 1]
    patches = signal[ys[:, None, None] + oy, xs[:, None, None] + ox].astype(np.float64)
    background = np.percentile(patches.reshape(len(xs), -1), 10, axis=1)
    patches = np.clip(patches - background[:, None, None], 0.0, None)
    sigma_w = 0.25 * pitch
    cx = np.zeros(len(xs))
    cy = np.zeros(len(xs))
    for _ in range(6):
        wgt = patches * np.exp(-((ox - cx[:, None, None]) ** 2 + (oy - cy[:, None, None]) ** 2)
                               / (2 * sigma_w**2))  # fmt: skip
        total = wgt.sum(axis=(1, 2))
        total[total <= 0] = np.nan
        cx = (wgt * ox).sum(axis=(1, 2)) / total
        cy = (wgt * oy).sum(axis=(1, 2)) / total
    good = np.isfinite(cx) & np.isfinite(cy)
    return np.column_stack([xs[good] + cx[good], ys[good] + cy[good]])


def _index_lattice(
    centres: FloatArray, cols: int, rows: int
) -> tuple[NDArray[np.intp], FloatArray] | str:
    """Grid coordinates of dot centres; ids row by row from the dot nearest the top left."""
    if len(centres) < 4:
        return f"only {len(centres)} dots segmented"
    from scipy.spatial import cKDTree

    tree = cKDTree(centres)
    _, nn = tree.query(centres, k=5)
    diffs = (centres[nn[:, 1:]] - centres[:, None, :]).reshape(-1, 2)
    pitch = float(np.median(np.linalg.norm(diffs, axis=1)))
    near = diffs[np.abs(np.linalg.norm(diffs, axis=1) - pitch) < 0.3 * pitch]
    angles = np.mod(np.arctan2(near[:, 1], near[:, 0]), np.pi)
    hist, edges = np.histogram(angles, bins=36, range=(0, np.pi))
    a0 = edges[np.argmax(hist)] + np.pi / 72
    close = np.abs(np.angle(np.exp(2j * (angles - a0)))) < 0.3
    a0 = float(np.angle(np.mean(np.exp(2j * angles[close]))) / 2)
    u = np.array([np.cos(a0), np.sin(a0)])
    v = np.array([-u[1], u[0]])
    if abs(u[0]) < abs(v[0]):  # u is the lattice direction closest to image x
        u, v = v, u
    u = u if u[0] > 0 else -u
    v = v if v[1] > 0 else -v
    # Lattice vectors with their own lengths (the grid may be seen in perspective).
    lu = near[np.abs(near @ u) > 0.8 * pitch]
    lv = near[np.abs(near @ v) > 0.8 * pitch]
    a = np.median(np.where((lu @ u)[:, None] > 0, lu, -lu), axis=0)
    b = np.median(np.where((lv @ v)[:, None] > 0, lv, -lv), axis=0)
    origin = centres[np.argmin(centres @ (u + v))]
    basis = np.column_stack([a, b])
    ij = np.rint(np.linalg.solve(basis, (centres - origin).T).T).astype(int)
    # Refine with a homography from the grid to the image and re-index once.
    H, _ = cv2.findHomography(ij.astype(np.float64), centres, 0)
    if H is not None:
        back = cv2.perspectiveTransform(centres.reshape(-1, 1, 2), np.linalg.inv(H)).reshape(-1, 2)
        ij = np.rint(back).astype(int)
    ij -= ij.min(axis=0)
    span = ij.max(axis=0) + 1
    if tuple(span) != (cols, rows) or len(np.unique(ij, axis=0)) != len(ij):
        return (
            f"dots form a {span[0]}x{span[1]} lattice, expected {cols}x{rows} "
            f"(all of the grid must be in view)"
        )
    return (ij[:, 1] * cols + ij[:, 0]).astype(np.intp), centres


def _detect_dotgrid(gray: NDArray[np.float32], target: Target) -> Detection:
    bright = float(np.median(gray)) < float(np.mean(gray))  # chrome dots on dark glass
    centres = _dot_centres(gray, bright)
    cols, rows = target.pattern_size
    if len(centres) < cols * rows:
        return Detection.none(f"found {len(centres)} dots, expected {cols * rows}")
    if len(centres) > cols * rows:
        return Detection.none(f"found {len(centres)} blobs, expected {cols * rows} dots")
    indexed = _index_lattice(centres, cols, rows)
    if isinstance(indexed, str):
        return Detection.none(indexed)
    ids, q = indexed
    order = np.argsort(ids)
    ids, q = ids[order], q[order]
    return Detection(True, ids, q, _homography_rms(target, ids, q), method="dots")


def _detect_charuco(gray: NDArray[np.float32], target: Target) -> Detection:
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_250)
    board = cv2.aruco.CharucoBoard(
        (target.cols, target.rows), target.pitch_um, target.feature_um, dictionary,
        target.marker_ids(),
    )  # fmt: skip
    detector = cv2.aruco.CharucoDetector(board)
    corners, ids, _, _ = detector.detectBoard(_to_uint8(gray))
    if ids is None or len(ids) < 4:
        return Detection.none("no ChArUco corners found")
    found_ids = np.asarray(ids, dtype=np.intp).reshape(-1)
    q = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    cols = target.pattern_size[0]
    ij = np.column_stack([found_ids % cols, found_ids // cols]).astype(np.float64)
    # the windows stay inside the white squares' margin round their markers
    margin = 0.5 * (target.pitch_um - target.feature_um) / target.pitch_um
    fractions = tuple(f for f in WINDOW_FRACTIONS if f <= margin) or (min(WINDOW_FRACTIONS),)
    q = refine_grid_corners(gray, q, ij, fractions=fractions).corners_px
    return Detection(True, found_ids, q, _homography_rms(target, found_ids, q), method="charuco")


def detect(
    image: NDArray[np.generic],
    target: Target,
    *,
    roi: tuple[int, int, int, int] | None = None,
    previous_px: FloatArray | None = None,
) -> Detection:
    """Find a target in an image.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        8 or 16 bit, or float; colour in OpenCV's BGR order.
    target : Target
    roi : (x0, y0, x1, y1), optional
        Search only this box (end exclusive); positions are still in whole-image pixels.
    previous_px : (N, 2) float, optional
        A plain chessboard's corners found in the frame before (whole-image pixels, as
        this function numbered them): refined from there when the board has moved less than
        a quarter of a square, searched for as usual otherwise. Other targets ignore it.

    Returns
    -------
    Detection
        ``found=False`` with a reason when the target is not (all) there.
    """
    img = np.asarray(image)
    x0 = y0 = 0
    if roi is not None and img.ndim in (2, 3):  # crop first: only the box is converted
        h, w = img.shape[:2]
        x0, y0 = max(0, int(roi[0])), max(0, int(roi[1]))
        x1, y1 = min(w, int(roi[2])), min(h, int(roi[3]))
        if x1 - x0 < 8 or y1 - y0 < 8:
            return Detection.none(f"region of interest {roi} is outside the {w}x{h} image")
        img = img[y0:y1, x0:x1]
    gray = to_gray(img)
    bad = int(np.count_nonzero(~np.isfinite(gray)))
    if bad:
        where = "region of interest" if roi is not None else "image"
        return Detection.none(f"the {where} has {bad} NaN or infinite pixels")
    if target.kind == "chessboard" and target.markers:
        det = detect_marker_chessboard(gray, _to_uint8(gray), target)
    elif target.kind == "chessboard":
        det = Detection.none("")
        if previous_px is not None:
            det = _track_chessboard(gray, target, np.asarray(previous_px, float) - (x0, y0))
        if not det.found:
            det = _detect_chessboard_coarse_to_fine(gray, target)
    elif target.kind == "dotgrid" and target.markers:
        det = detect_marker_grid(gray, target)
    elif target.kind == "dotgrid":
        det = _detect_dotgrid(gray, target)
    else:
        det = _detect_charuco(gray, target)
    if det.found and (x0 or y0):
        det = Detection(
            True, det.ids, np.add(det.q_px, (x0, y0)), det.quality_px, method=det.method
        )
    return det
