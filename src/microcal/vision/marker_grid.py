"""Dot grids of which any part is in view, numbered from hollow marker dots.

A calibration slide under a microscope is larger than the field: no image shows the whole
grid, so the dots cannot be numbered from the grid's corner. Hollow ("donut") dots at known
grid positions (the target spec's ``markers=``) fix the numbering instead:

1. **Dots.** The lattice's pitch is read from the image's spectrum; dots are the blobs of a
   local threshold over about two pitches (uneven illumination), kept when their size and
   roundness agree with the others and they do not touch the image's edge; a blob with a
   hole in it is a marker.
2. **Lattice.** From the dot nearest the image's centre the lattice is walked step by step,
   each step predicted from the last one taken in that direction (perspective and lens
   distortion bend the lattice slowly), so any part of a grid, however distorted, is
   indexed; dots the walk does not reach are left out.
3. **Centres.** :func:`~microcal.vision.dot_centres.refine_dot_centres`: the centroid of the
   normalised signal, less the bias of perspective from the local homography.
4. **Numbering.** Of the eight ways the lattice can lie on the slide (four turns, seen from
   the front or through the glass), the one that puts every hollow dot seen on a marker of
   the spec, and no marker on a solid dot seen, gives each dot its grid position; a slide
   seen from the front is preferred when both fit (a layout that is its own mirror image).
   Where no way fits (the spec does not match the slide), or several do (too few markers in
   view), the view is not numbered and the detection says why.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import InputError
from .detection import Detection, homography_rms_px
from .dot_centres import refine_dot_centres
from .target_region import textured_box
from .targets import Target, marker_text

__all__ = ["MarkerMismatch", "check_marker_spec", "detect_marker_grid", "find_lattice_dots"]

#: Smallest lattice pitch the spectrum is searched for, px.
MIN_PITCH_PX = 5.0
#: A blob's area may differ from the median dot's by this factor and still be a dot.
AREA_FACTOR = 2.5
#: A blob is round enough to be a dot above this 4 pi area / perimeter².
MIN_ROUNDNESS = 0.45
#: A hole counts (a marker) above this share of its dot's area, ...
MIN_HOLE_SHARE = 0.04
#: ... centred on the dot within this share of the dot's radius.
HOLE_CENTRING = 0.3
#: A step of the walk lands on a dot within this share of the step.
STEP_TOLERANCE = 0.3

MISMATCH_PREFIX = "the hollow dots seen do not match the spec's markers"


@dataclass
class LatticeDots:
    """Dots found in an image and their lattice positions (the walk's own frame).

    Attributes
    ----------
    q_px : (N, 2) float
        Centres, px.
    ij : (N, 2) int
        Lattice steps from the first dot along the image's x-most and y-most lattice axes.
    hollow : (N,) bool
    radius : float
        The dots' radius, pitches.
    hole_radius : (N,) float
        Holes' radii, pitches (0 for solid dots).
    dark : bool
        Dark dots on a light ground.
    reason : str
        Why no lattice was found ("" when it was).
    """

    q_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    ij: NDArray[np.intp] = field(default_factory=lambda: np.zeros((0, 2), dtype=np.intp))
    hollow: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    radius: float = 0.0
    hole_radius: FloatArray = field(default_factory=lambda: np.zeros(0))
    dark: bool = True
    reason: str = ""


def _spectral_pitch_px(gray: NDArray[np.float32]) -> float:
    """The lattice's pitch from the strongest peak of the image's spectrum, px (0 if none)."""
    h, w = gray.shape
    side = 1 << int(np.floor(np.log2(min(h, w, 1024))))
    y0, x0 = (h - side) // 2, (w - side) // 2
    crop = gray[y0 : y0 + side, x0 : x0 + side].astype(np.float64)
    crop = crop - cv2.blur(crop, (side // 8, side // 8))
    win = np.hanning(side)
    spec = np.abs(np.fft.fftshift(np.fft.fft2(crop * np.outer(win, win))))
    fy, fx = np.mgrid[-side // 2 : side // 2, -side // 2 : side // 2]
    radius = np.hypot(fx, fy)
    spec[(radius < 3) | (radius > side / MIN_PITCH_PX)] = 0
    k = int(np.argmax(spec))
    r = float(radius.ravel()[k])
    return side / r if r > 0 else 0.0


def _dark_dots(gray: NDArray[np.float32], pitch_px: float) -> bool:
    """Dark dots on a light ground: the detail finer than a pitch is skewed to the dark side
    (dots cover less of the image than the ground; unlike the median against the mean, the
    test ignores uneven light)."""
    scale = min(1.0, 12.0 / pitch_px)  # about 12 px per pitch is plenty
    small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    detail = small.astype(np.float64) - cv2.blur(small, (int(2 * pitch_px * scale) | 1,) * 2)
    detail -= detail.mean()
    return float(np.mean(detail**3)) < 0


@dataclass
class _Blob:
    centre: FloatArray
    area: float
    hole_area: float


def _blobs(gray: NDArray[np.float32], dark: bool, pitch_px: float) -> list[_Blob]:
    lo, hi = np.percentile(gray, (0.5, 99.5))
    img8 = np.clip((gray - lo) * (255.0 / max(hi - lo, 1e-9)), 0, 255).astype(np.uint8)
    if not dark:
        img8 = 255 - img8
    # threshold halfway between the local ground (a grey closing over a pitch: the dots
    # removed) and the local dot level (an opening): uneven light, and holes only partly
    # resolved, still split at their own mid-level
    # (on a copy shrunk to about 12 px per pitch: the levels vary over pitches, not pixels)
    smooth = cv2.GaussianBlur(img8, (0, 0), max(0.7, 0.03 * pitch_px))
    scale = min(1.0, 12.0 / pitch_px)
    small = cv2.resize(smooth, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    size = 2 * round(0.6 * pitch_px * scale) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    ground = cv2.morphologyEx(small, cv2.MORPH_CLOSE, kernel).astype(np.float32)
    ink = cv2.erode(small, kernel).astype(np.float32)
    sigma = 0.5 * pitch_px * scale
    ground, ink = cv2.GaussianBlur(ground, (0, 0), sigma), cv2.GaussianBlur(ink, (0, 0), sigma)
    h, w = gray.shape
    level = cv2.resize(0.5 * (ground + ink), (w, h), interpolation=cv2.INTER_LINEAR)
    contrast = cv2.resize(ground - ink, (w, h), interpolation=cv2.INTER_LINEAR)
    binary = ((smooth < level) & (contrast > 8)).astype(np.uint8) * 255
    contours, hierarchy = cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if hierarchy is None:
        return []
    h, w = gray.shape
    out = []
    hier = hierarchy[0]
    for k, cnt in enumerate(contours):
        if hier[k][3] != -1:  # a hole: counted with its parent
            continue
        x, y, bw, bh = cv2.boundingRect(cnt)
        if x <= 1 or y <= 1 or x + bw >= w - 1 or y + bh >= h - 1:
            continue  # cut by the image's edge
        m = cv2.moments(cnt)
        area = m["m00"]
        if area < 3:
            continue
        perimeter = cv2.arcLength(cnt, True)
        if 4 * np.pi * area / max(perimeter**2, 1e-9) < MIN_ROUNDNESS:
            continue
        centre = np.array([m["m10"] / area, m["m01"] / area])
        hole = 0.0
        child = hier[k][2]
        while child != -1:  # the largest hole near the middle (noise leaves small, stray ones)
            mh = cv2.moments(contours[child])
            if mh["m00"] > hole:
                off = np.hypot(mh["m10"] / mh["m00"] - centre[0], mh["m01"] / mh["m00"] - centre[1])
                if off < HOLE_CENTRING * np.sqrt(area / np.pi):
                    hole = mh["m00"]
            child = hier[child][0]
        out.append(_Blob(centre, area, hole if hole > MIN_HOLE_SHARE * area else 0.0))
    return out


def _lattice_axes(c: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """The two lattice steps (image x-most first, both pointing to +x / +y), px."""
    from scipy.spatial import cKDTree

    _, nn = cKDTree(c).query(c, k=5)
    diffs = (c[nn[:, 1:]] - c[:, None, :]).reshape(-1, 2)
    length = np.linalg.norm(diffs, axis=1)
    pitch = float(np.median(length))
    near = diffs[np.abs(length - pitch) < 0.3 * pitch]
    if len(near) < 4:
        return None
    angles = np.mod(np.arctan2(near[:, 1], near[:, 0]), np.pi)
    hist, edges = np.histogram(angles, bins=36, range=(0, np.pi))
    a0 = edges[np.argmax(hist)] + np.pi / 72
    close = np.abs(np.angle(np.exp(2j * (angles - a0)))) < 0.3
    a0 = float(np.angle(np.mean(np.exp(2j * angles[close]))) / 2)
    u = np.array([np.cos(a0), np.sin(a0)])
    v = np.array([-u[1], u[0]])
    if abs(u[0]) < abs(v[0]):
        u, v = v, u
    u = u if u[0] > 0 else -u
    v = v if v[1] > 0 else -v
    lu = near[np.abs(near @ u) > 0.8 * pitch]
    lv = near[np.abs(near @ v) > 0.8 * pitch]
    if len(lu) == 0 or len(lv) == 0:
        return None
    a = np.median(np.where((lu @ u)[:, None] > 0, lu, -lu), axis=0)
    b = np.median(np.where((lv @ v)[:, None] > 0, lv, -lv), axis=0)
    return a, b


def _walk(c: FloatArray, a: FloatArray, b: FloatArray) -> NDArray[np.intp]:
    """Lattice positions (N, 2) by walking from the dot nearest the centroid; -10**9 where
    the walk did not reach."""
    from scipy.spatial import cKDTree

    tree = cKDTree(c)
    n = len(c)
    unset = -(10**9)
    ij = np.full((n, 2), unset, dtype=np.intp)
    steps = np.zeros((n, 2, 2))
    seed = int(np.argmin(np.linalg.norm(c - c.mean(axis=0), axis=1)))
    ij[seed] = 0
    steps[seed] = a, b
    queue = [seed]
    while queue:
        k = queue.pop(0)
        for axis in (0, 1):
            for sign in (1, -1):
                step = sign * steps[k, axis]
                dist, m = tree.query(c[k] + step)
                if dist > STEP_TOLERANCE * float(np.linalg.norm(step)) or ij[m, 0] != unset:
                    continue
                ij[m] = ij[k]
                ij[m, axis] += sign
                steps[m] = steps[k]
                steps[m, axis] = sign * (c[m] - c[k])
                queue.append(int(m))
    return ij


def find_lattice_dots(gray: NDArray[np.float32]) -> LatticeDots:
    """The dots of a (partial) dot grid in an image, on their lattice, centres refined.

    Parameters
    ----------
    gray : (H, W) float32

    Returns
    -------
    LatticeDots
        With ``reason`` set when no lattice of dots was found.
    """
    pitch = _spectral_pitch_px(gray)
    if pitch < MIN_PITCH_PX:
        return LatticeDots(reason="no lattice of dots found (no period in the image)")
    dark = _dark_dots(gray, pitch)
    blobs = _blobs(gray, dark, pitch)
    if len(blobs) < 9:
        return LatticeDots(reason=f"only {len(blobs)} dots found, no grid")
    area = np.array([b.area for b in blobs])
    typical = float(np.median(area[area > 0.01 * pitch**2])) if np.any(area > 0.01 * pitch**2) \
        else float(np.median(area))  # fmt: skip
    keep = [b for b, s in zip(blobs, area, strict=True)
            if typical / AREA_FACTOR < s < typical * AREA_FACTOR]  # fmt: skip
    if len(keep) < 9:
        return LatticeDots(reason=f"only {len(keep)} dots of one size found, no grid")
    c = np.array([b.centre for b in keep])
    axes = _lattice_axes(c)
    if axes is None:
        return LatticeDots(reason="the dots found form no lattice")
    ij = _walk(c, *axes)
    reached = ij[:, 0] > -(10**8)
    if np.count_nonzero(reached) < 9:
        return LatticeDots(reason="the dots found form no lattice")
    c, ij = c[reached], ij[reached]
    keep = [b for b, r in zip(keep, reached, strict=True) if r]
    ij -= ij.min(axis=0)
    # the dots' radius in pitches: each dot's area over the local lattice cell's
    hollow = np.array([b.hole_area > 0 for b in keep])
    cell = _cell_areas_px(ij, c)
    outer = np.array([b.area for b in keep])
    with np.errstate(invalid="ignore", divide="ignore"):
        r_each = np.sqrt(outer / (np.pi * cell))
        hole_each = np.sqrt(np.array([b.hole_area for b in keep]) / (np.pi * cell))
    solid = np.isfinite(r_each) & ~hollow
    if not np.any(solid):
        return LatticeDots(reason="the dots found form no lattice")
    radius = float(np.clip(np.median(r_each[solid]), 0.05, 0.45))
    holes = np.where(hollow & np.isfinite(hole_each), hole_each, 0.0)
    q, ok = refine_dot_centres(gray, c, ij, radius, dark=dark, hole_radius=holes)
    if np.count_nonzero(ok) < 9:
        return LatticeDots(reason="the dots found are too near the image's edge to locate")
    return LatticeDots(q[ok], ij[ok], hollow[ok], radius, holes[ok], dark)


def _cell_areas_px(ij: NDArray[np.intp], c: FloatArray) -> FloatArray:
    """Area of one lattice cell at each dot, px², from the nearest neighbours' steps."""
    index = {(int(a), int(b)): k for k, (a, b) in enumerate(ij)}
    out = np.full(len(c), np.nan)
    for k, (a, b) in enumerate(ij):
        du = [c[index[(a + s, b)]] - c[k] for s in (1, -1) if (a + s, b) in index]
        dv = [c[index[(a, b + s)]] - c[k] for s in (1, -1) if (a, b + s) in index]
        if du and dv:
            u = np.mean([d * (1 if i == 0 or len(du) == 1 else -1) for i, d in enumerate(du)],
                        axis=0) if len(du) == 2 else du[0]  # fmt: skip
            v = np.mean([d * (1 if i == 0 or len(dv) == 1 else -1) for i, d in enumerate(dv)],
                        axis=0) if len(dv) == 2 else dv[0]  # fmt: skip
            out[k] = abs(float(u[0] * v[1] - u[1] * v[0]))
    return out


#: The eight ways a lattice can lie on the slide: four turns, seen from the front or the back.
_WAYS = [np.array(m) for m in (
    ((1, 0), (0, 1)), ((0, -1), (1, 0)), ((-1, 0), (0, -1)), ((0, 1), (-1, 0)),
    ((1, 0), (0, -1)), ((0, 1), (1, 0)), ((-1, 0), (0, 1)), ((0, -1), (-1, 0)),
)]  # fmt: skip


@dataclass(frozen=True)
class MarkerMismatch:
    """Hollow dots seen that no placement of the spec's markers explains."""

    seen: int
    suggestion: str


def _number(dots: LatticeDots, target: Target) -> tuple[NDArray[np.intp], str]:
    """Grid positions (N, 2) (column, row) of the dots, or a reason."""
    layout = {tuple(p) for p in target.markers}
    seen = dots.ij[dots.hollow]
    n_markers = len(target.markers)
    if len(seen) == 0:
        return dots.ij, (
            f"none of the slide's {n_markers} hollow marker dots is in view "
            f"({len(dots.ij)} dots seen); move the slide so that its markers are"
        )
    solid = {tuple(p) for p in dots.ij[~dots.hollow].tolist()}
    fits: list[tuple[int, NDArray[np.intp], NDArray[np.intp]]] = []
    on_solid = 0  # placements refused only for a marker on a dot seen solid
    anchor = seen[0]
    for w, S in enumerate(_WAYS):
        for m in target.markers:
            t = np.array(m) - S @ anchor
            placed = seen @ S.T + t
            if not all(tuple(p) in layout for p in placed.tolist()):
                continue
            Sinv = np.rint(np.linalg.inv(S)).astype(int)
            back = (np.array(target.markers) - t) @ Sinv.T
            if any(tuple(p) in solid for p in back.tolist()):
                on_solid += 1
                continue
            if not any(np.array_equal(S, f[1]) and np.array_equal(t, f[2]) for f in fits):
                fits.append((w, S, t))
    front = [f for f in fits if f[0] < 4]
    chosen = front if front else fits
    if len(chosen) == 1:
        _, S, t = chosen[0]
        return dots.ij @ S.T + t, ""
    if not fits and on_solid:
        return dots.ij, (
            f"{len(seen)} hollow marker dot(s) seen, but the spec's markers would put others on "
            f"dots seen solid: a hole too small to resolve (about "
            f"{2 * float(np.max(dots.hole_radius)):.2f} pitch across) or a spec that does not "
            f"match the slide"
        )
    if not fits:
        return dots.ij, _mismatch_reason(seen, target)
    return dots.ij, (
        f"{len(seen)} of the slide's {n_markers} hollow marker dots in view fit the spec's "
        f"markers in {len(chosen)} ways; bring more of the markers into view"
    )


def _mismatch_reason(seen: NDArray[np.intp], target: Target) -> str:
    """The one line for hollow dots no placement of the markers explains, with a fix: the
    placement of what is seen nearest to the spec's markers, in the spec's order."""
    spec = np.array(target.markers)
    best: tuple[float, NDArray[np.intp]] | None = None
    for S in _WAYS[:4]:
        placed = seen @ S.T
        for anchor in placed:
            for m in spec:
                moved = placed - anchor + m
                if moved.min() < 0 or np.any(moved.max(axis=0) >= (target.cols, target.rows)):
                    continue
                d = np.abs(spec[:, None, :] - moved[None, :, :]).sum(axis=2)
                cost = float(d.min(axis=1).sum() + d.min(axis=0).sum())
                if best is None or cost < best[0]:
                    best = (cost, moved)
    fix = "check the markers' positions"
    if best is not None:
        moved = best[1]
        order: list[int] = []
        for m in spec:  # each spec marker's nearest, in the spec's order
            free = [k for k in range(len(moved)) if k not in order]
            if free:
                order.append(min(free, key=lambda k: int(np.abs(moved[k] - m).sum())))
        text = marker_text(tuple((int(moved[k][0]), int(moved[k][1])) for k in order))
        fix = f"markers={text} would fit this view"
    return (
        f"{MISMATCH_PREFIX} (markers={marker_text(target.markers)}): {len(seen)} hollow "
        f"dot(s) at lattice steps {_steps_text(seen)} from the first; {fix}"
    )


def _steps_text(seen: NDArray[np.intp]) -> str:
    d = seen - seen[0]
    text = ", ".join(f"({int(p[0])},{int(p[1])})" for p in d[1:6]) or "(none)"
    return text + (", ..." if len(d) > 6 else "")


def detect_marker_grid(
    gray: NDArray[np.float32], target: Target, *, whole: bool = False
) -> Detection:
    """The visible part of a dot grid, numbered from its hollow marker dots.

    Parameters
    ----------
    gray : (H, W) float32
    target : Target
        A dot grid with ``markers``.
    whole : bool
        Search the whole image; by default a target covering a small part of a large,
        mostly empty image is searched in its textured region
        (:func:`~microcal.vision.target_region.textured_box`).

    Returns
    -------
    Detection
        ids into ``target.points_um()`` of the dots seen that lie on the spec's grid, their
        refined centres; ``found=False`` with the reason where the markers are not seen,
        are ambiguous or do not match the spec.
    """
    box = None if whole else textured_box(gray, _spectral_pitch_px(gray))
    if box is not None:  # a target covering a part of a large, mostly empty frame
        x0, y0, x1, y1 = box
        det = detect_marker_grid(gray[y0:y1, x0:x1], target, whole=True)
        if not det.found:
            return det
        return Detection(True, det.ids, det.q_px + (x0, y0), det.quality_px, method=det.method)
    dots = find_lattice_dots(gray)
    if dots.reason:
        return Detection.none(dots.reason)
    grid, why = _number(dots, target)
    if why:
        return Detection.none(why)
    inside = (grid[:, 0] >= 0) & (grid[:, 1] >= 0) & (grid[:, 0] < target.cols) & \
        (grid[:, 1] < target.rows)  # fmt: skip
    if np.count_nonzero(inside) < 4:
        return Detection.none(
            f"only {np.count_nonzero(inside)} of the {len(grid)} dots seen lie on the spec's "
            f"{target.cols}x{target.rows} grid; give the grid of the whole slide"
        )
    ids = (grid[inside, 1] * target.cols + grid[inside, 0]).astype(np.intp)
    q = dots.q_px[inside]
    order = np.argsort(ids)
    ids, q = ids[order], q[order]

    left = len(grid) - len(ids)
    method = "marker dots" + (f" ({left} beyond the spec's grid left out)" if left else "")
    return Detection(True, ids, q, homography_rms_px(target, ids, q), method=method)


def check_marker_spec(target: Target, detections: list[Detection]) -> None:
    """Refuse a marker spec that the slide (dot grid or chessboard) contradicts in most views
    where markers are seen.

    Parameters
    ----------
    target : Target
    detections : list of Detection
        Every view of every camera.

    Raises
    ------
    InputError
        One line naming the mismatch and the markers that would fit, when the views whose
        hollow dots contradict the spec are at least as many as those numbered by it.
    """
    if not target.markers:
        return
    from .chessboard_markers import MISMATCH_PREFIX as CIRCLES_MISMATCH

    prefixes = (MISMATCH_PREFIX, CIRCLES_MISMATCH)
    mismatches = [d.reason for d in detections if d.reason.startswith(prefixes)]
    numbered = sum(d.found for d in detections)
    if mismatches and len(mismatches) >= numbered:
        raise InputError(
            f"target {target.spec}: {mismatches[0]} (in {len(mismatches)} of "
            f"{len(detections)} images)"
        )
