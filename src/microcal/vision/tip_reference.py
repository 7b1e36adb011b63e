"""The tool's own reference: images of this very tool at known focus offsets, matched by
normalised cross-correlation, the match refined to sub-pixel precision, with its uncertainty.

A reference is taken once per tool (when it is mounted): frames with the tool's tip at one
place and the focus stepped through known offsets, the tip located in the frame in focus (by
the model fit, averaged over frames at known offsets across the field), and a window around
it cut from every frame. Matching a new image:

- every other template is correlated over the image at half its resolution (OpenCV's
  ``TM_CCOEFF_NORMED``), which picks the template and the place; the best and its neighbours
  are correlated again at full resolution around that place: the best names the focus offset
  (interpolated between the neighbours' scores);
- the peak is refined by Gauss-Newton on the shift, the template moved by bicubic
  interpolation and scaled in brightness and contrast to the image (least squares);
- its covariance is the noise of that fit over the template's gradient energy,
  ``sigma^2 (sum grad T grad T^T)^-1``, plus the reference's own scatter (how well frames at
  known offsets were found again).

A match whose correlation is below a floor is no tip; a second peak as high, away from the
first, is two tools.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import InputError
from .detect import to_gray
from .tip import TipDetection

__all__ = ["TipReference", "build_reference", "match_tip", "with_scatter"]

#: Least correlation of a match.
MIN_SCORE = 0.8


@dataclass(frozen=True)
class TipReference:
    """Windows of one tool around its tip, at known focus offsets.

    Attributes
    ----------
    templates : (K, h, w) float32
    focus_um : (K,) float
        The focus offset of each template, µm (increasing).
    anchor_px : (2,) float
        The tip point in the templates' pixels.
    scatter_px : float
        1-sigma per axis with which frames at known offsets were found again (0: unknown).
    """

    templates: NDArray[np.float32]
    focus_um: FloatArray
    anchor_px: FloatArray
    scatter_px: float = 0.0


def build_reference(
    frames: Sequence[NDArray[np.generic]],
    focus_um: Sequence[float] | FloatArray,
    apex_px: FloatArray,
    *,
    half_px: int = 20,
) -> TipReference:
    """A reference from frames with the tip at ``apex_px`` and the focus at ``focus_um``.

    Parameters
    ----------
    frames : sequence of (H, W) images
        The tool in one place, the focus stepped.
    focus_um : sequence of float
        The focus offset of each frame, µm.
    apex_px : (2,) float
        The tip point in the frames (found by the model fit in the frame in focus).
    half_px : int
        The window's half size: it is ``2 half_px + 1`` pixels wide.
    """
    if len(frames) != len(focus_um) or not frames:
        raise InputError(
            f"reference: expected as many focus offsets as frames, got {len(focus_um)} for "
            f"{len(frames)}"
        )
    apex = np.asarray(apex_px, dtype=np.float64)
    cx, cy = round(apex[0]), round(apex[1])
    order = np.argsort(np.asarray(focus_um, dtype=np.float64))
    tiles = []
    for i in order:
        gray = to_gray(np.asarray(frames[i]))
        h, w = gray.shape
        if not (half_px <= cx < w - half_px and half_px <= cy < h - half_px):
            raise InputError("reference: the tip is too near the frame's edge for its window")
        tiles.append(gray[cy - half_px : cy + half_px + 1, cx - half_px : cx + half_px + 1])
    anchor = apex - np.array([cx - half_px, cy - half_px], dtype=np.float64)
    return TipReference(np.stack(tiles).astype(np.float32),
                        np.asarray(focus_um, dtype=np.float64)[order], anchor)  # fmt: skip


def _refine(
    gray: NDArray[np.float32], template: NDArray[np.float32], corner: FloatArray
) -> tuple[FloatArray, FloatArray] | None:
    """Sub-pixel place of ``template``'s corner near ``corner`` (Gauss-Newton on the shift,
    brightness and contrast solved), and its covariance; None when it runs off the image."""
    th, tw = template.shape
    h, w = gray.shape
    gx = cv2.Sobel(template, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(template, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    pos = corner.astype(np.float64).copy()
    cov = np.full((2, 2), np.nan)
    for _ in range(6):
        # The image around the template's place, moved so the template sits on whole pixels.
        M = np.array([[1.0, 0.0, pos[0]], [0.0, 1.0, pos[1]]], dtype=np.float64)
        if not (pos[0] >= 0 and pos[0] + tw < w - 1 and pos[1] >= 0 and pos[1] + th < h - 1):
            return None
        patch = cv2.warpAffine(gray, M, (tw, th), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
        tv, pv = template.ravel().astype(np.float64), patch.ravel().astype(np.float64)
        tc = tv - tv.mean()
        b = float(tc @ (pv - pv.mean())) / max(float(tc @ tc), 1e-12)
        a = float(pv.mean()) - b * float(tv.mean())
        r = pv - (a + b * tv)
        J = np.column_stack([b * gx.ravel(), b * gy.ravel()]).astype(np.float64)
        H = J.T @ J
        try:
            step = np.linalg.solve(H, -J.T @ r)
        except np.linalg.LinAlgError:
            return None
        pos += step
        noise = float(r @ r) / max(r.size - 4, 1)
        cov = np.linalg.inv(H) * noise
        if float(np.hypot(*step)) < 1e-3:
            break
    return pos, cov


def match_tip(
    image: NDArray[np.generic],
    reference: TipReference,
    *,
    roi: tuple[int, int, int, int] | None = None,
    min_score: float = MIN_SCORE,
) -> TipDetection:
    """Find the tool's tip by its reference (see the module docstring).

    Returns
    -------
    TipDetection
        ``method="reference"``; the apex, its covariance, the correlation (``score``) and
        the focus offset, or ``found=False`` with the reason.
    """
    gray = to_gray(np.asarray(image))
    x0 = y0 = 0
    if roi is not None:
        h, w = gray.shape
        x0, y0 = max(0, int(roi[0])), max(0, int(roi[1]))
        gray = gray[y0 : min(h, int(roi[3])), x0 : min(w, int(roi[2]))]
    K, th, tw = reference.templates.shape
    if gray.shape[0] <= th or gray.shape[1] <= tw:
        return TipDetection.none("the image is smaller than the reference's window", "reference")
    # Coarse: every template at half the resolution picks the focus and the place.
    small = cv2.pyrDown(gray)
    every = list(range(0, K, 2)) if K > 4 else list(range(K))
    coarse = {k: cv2.matchTemplate(small, cv2.pyrDown(reference.templates[k]),
                                   cv2.TM_CCOEFF_NORMED) for k in every}  # fmt: skip
    best = max(coarse, key=lambda k: float(coarse[k].max()))
    cmap = coarse[best]
    peak = np.unravel_index(int(np.argmax(cmap)), cmap.shape)
    cy, cx = int(peak[0]), int(peak[1])
    # A second peak as high, farther than two windows from the first: two tools.
    far = cmap.copy()
    far[max(cy - th, 0) : cy + th + 1, max(cx - tw, 0) : cx + tw + 1] = -1.0
    # Fine: the neighbouring templates in full resolution around the coarse place.
    h, w = gray.shape
    m = 5
    gx0, gy0 = max(2 * cx - m, 0), max(2 * cy - m, 0)
    sub = gray[gy0 : min(2 * cy + th + m, h), gx0 : min(2 * cx + tw + m, w)]
    picks = [k for k in (best - 1, best, best + 1) if 0 <= k < K]
    fine = {k: cv2.matchTemplate(sub, reference.templates[k], cv2.TM_CCOEFF_NORMED) for k in picks}
    scores = {k: float(v.max()) for k, v in fine.items()}
    best = max(scores, key=lambda k: scores[k])
    score = scores[best]
    if score < min_score:
        return TipDetection.none(
            f"no tool like the reference in view (best correlation {score:.2f}, at least "
            f"{min_score:g})", "reference",
        )  # fmt: skip
    if far.size and float(far.max()) > max(min_score, score - 0.1):
        return TipDetection.none("2 tools in view: expected one", "reference")
    res = fine[best]
    py, px = np.unravel_index(int(np.argmax(res)), res.shape)
    ix, iy = int(px) + gx0, int(py) + gy0
    if ix <= 0 or iy <= 0 or ix >= w - tw or iy >= h - th:
        return TipDetection.none("the tip is out of the field (the match is at the edge)",
                                 "reference")  # fmt: skip
    refined = _refine(gray, reference.templates[best], np.array([ix, iy], dtype=np.float64))
    if refined is None or float(np.hypot(*(refined[0] - (ix, iy)))) > 2.5:
        return TipDetection.none("the match did not settle to sub-pixel precision", "reference")
    corner, cov = refined
    cov = cov + np.eye(2) * reference.scatter_px**2
    focus = float(reference.focus_um[best])
    if best - 1 in scores and best + 1 in scores:  # a parabola through the neighbours' scores
        s0, s1, s2 = scores[best - 1], score, scores[best + 1]
        denom = s0 - 2 * s1 + s2
        if denom < 0:
            frac = 0.5 * (s0 - s2) / denom
            step = 0.5 * (reference.focus_um[best + 1] - reference.focus_um[best - 1])
            focus += float(np.clip(frac, -1.0, 1.0)) * step
    apex = corner + reference.anchor_px + (x0, y0)
    return TipDetection(True, apex, cov, method="reference", score=score,
                        focus_offset_um=focus)  # fmt: skip


def with_scatter(reference: TipReference, errors_px: FloatArray) -> TipReference:
    """The reference with its scatter from the errors (N, 2) of frames at known offsets."""
    e = np.asarray(errors_px, dtype=np.float64).reshape(-1, 2)
    scatter = float(math.sqrt(np.mean(np.sum((e - e.mean(axis=0)) ** 2, axis=1)) / 2))
    return TipReference(reference.templates, reference.focus_um, reference.anchor_px, scatter)
