"""Detection of a tool's tip: the apex in pixels with its covariance, the axis, or the reason.

Four methods, chosen per tool and named in the answer (``method``):

- ``"fast fit"`` (:mod:`~microcal.vision.tip_fast`): the tool found coarsely on the image
  halved, then a closed-form image of its end (a taper cut at its rounded end, blurred; for
  glass, its refractive darkness besides) fitted to a patch around the tip by
  Levenberg-Marquardt: a few milliseconds on a 256 x 256 region; the default for a needle, a
  jaw or a tool of any kind;
- ``"model fit"`` (:mod:`~microcal.vision.tip_fit`): the tool found coarsely
  (:mod:`~microcal.vision.tip_find`), then its outline fitted to sub-pixel precision: the
  edges of the taper, their meeting point corrected for the rounded end (what the
  measurement takes for a needle or a pipette whose spec gives its size, for its vertex);
- ``"image fit"`` (:mod:`~microcal.vision.tip_image_model`): the tool found coarsely, then
  the image of a tapered tool (outline, glass or opaque, blur growing along it) drawn and
  fitted to the pixels around its end (the most exact, and the slowest; the default for a
  glass pipette, whose dark walls and lighter lumen it draws as the simulator does);
- ``"reference"`` (:mod:`~microcal.vision.tip_reference`): images of this very tool grabbed
  at known focus offsets, matched by normalised cross-correlation with a sub-pixel peak.

The apex is the image of the *tip point* (``docs/conventions.md``): on the tool's axis, the
centre of the rounded end (needle, jaw) or of the opening (pipette), so that every camera
sees the same point of the tool. A failure is not an error: ``found=False`` with the reason
(no tool, two tools, the tip out of the field, too defocused).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import InputError
from .detect import to_gray
from .tip_fast import coarse_tool, fast_tip_fit
from .tip_find import ToolBlob, find_tool
from .tip_fit import TipFit, fit_tip
from .tip_image_model import fit_tip_image
from .tip_target import TipTarget

__all__ = ["MAX_BLUR_PX", "TIP_METHODS", "TipDetection", "default_method", "detect_tip"]

#: Beyond this blur at the tip (Gaussian sigma, px) a tool is too defocused to locate.
MAX_BLUR_PX = 6.0
#: The methods of :func:`detect_tip`.
TIP_METHODS = ("fast fit", "model fit", "image fit")


def default_method(target: TipTarget) -> str:
    """The method :func:`detect_tip` uses for a tool: the image fit for a glass pipette (the
    fast fit's closed form misses its figures: ``docs/vision.md``), the fast fit otherwise."""
    return "image fit" if target.kind == "pipette" else "fast fit"


def _nan2() -> FloatArray:
    return np.full(2, np.nan)


@dataclass(frozen=True)
class TipDetection:
    """A tool's tip found in one image (or why not).

    Attributes
    ----------
    found : bool
    apex_px : (2,) float
        The tip point's image, whole-image pixels (OpenCV convention).
    cov_px : (2, 2) float
        Its covariance, px^2.
    axis : (2,) float
        Unit direction of the tool's axis in the image, from the tip towards the shank.
    vertex_px : (2,) float
        Where the taper's edges meet (model fit; NaN for the reference method).
    half_angle_deg : float
        Half the angle between the edges in the image.
    blur_px : float
        Gaussian sigma of the blur at the tip, px.
    method : str
        ``"model fit"``, ``"image fit"`` or ``"reference"``.
    reason : str
        Why nothing was found ("" when found).
    score : float
        The reference method's correlation (1 = identical), NaN for the model fit.
    focus_offset_um : float
        The reference method's estimate of the tip's distance from the focal plane, µm.
    """

    found: bool
    apex_px: FloatArray = field(default_factory=_nan2)
    cov_px: FloatArray = field(default_factory=lambda: np.full((2, 2), np.nan))
    axis: FloatArray = field(default_factory=_nan2)
    vertex_px: FloatArray = field(default_factory=_nan2)
    half_angle_deg: float = float("nan")
    blur_px: float = float("nan")
    method: str = ""
    reason: str = ""
    score: float = float("nan")
    focus_offset_um: float = float("nan")

    @classmethod
    def none(cls, reason: str, method: str = "model fit") -> TipDetection:
        """Nothing found, for ``reason``."""
        return cls(False, method=method, reason=reason)

    @property
    def std_px(self) -> float:
        """RMS of the apex's standard deviations along x and y, px."""
        return float(math.sqrt(0.5 * np.trace(self.cov_px)))

    def shifted(self, dx: float, dy: float) -> TipDetection:
        """The same detection with its pixel positions moved by (dx, dy)."""
        d = np.array([dx, dy], dtype=np.float64)
        return TipDetection(self.found, self.apex_px + d, self.cov_px, self.axis,
                            self.vertex_px + d, self.half_angle_deg, self.blur_px, self.method,
                            self.reason, self.score, self.focus_offset_um)  # fmt: skip


def _crop(
    image: NDArray[np.generic], roi: tuple[int, int, int, int] | None
) -> tuple[NDArray[np.float32], int, int] | str:
    """The grey image inside ``roi`` and its origin, or the reason it has none."""
    img = np.asarray(image)
    if img.ndim not in (2, 3):
        raise InputError(f"image: expected (H, W) or (H, W, 3), got shape {img.shape}")
    x0 = y0 = 0
    if roi is not None:
        h, w = img.shape[:2]
        x0, y0 = max(0, int(roi[0])), max(0, int(roi[1]))
        x1, y1 = min(w, int(roi[2])), min(h, int(roi[3]))
        if x1 - x0 < 16 or y1 - y0 < 16:
            return f"region of interest {roi} is outside the {w}x{h} image"
        img = img[y0:y1, x0:x1]
    gray = to_gray(img)
    bad = int(np.count_nonzero(~np.isfinite(gray)))
    if bad:
        return f"the image has {bad} NaN or infinite pixels"
    return gray, x0, y0


#: How far a fit may follow a faint end along the coarse axis from the coarse tip, px.
_FOLLOW_PX = {"fast fit": 64.0, "image fit": 40.0}


def _fitted(
    gray: NDArray[np.float32], blob: ToolBlob, target: TipTarget, method: str, max_blur_px: float
) -> TipDetection:
    """The tip fitted by ``method`` from the coarse ``blob``, or why not."""
    fitters: dict[str, Callable[[NDArray[np.float32], ToolBlob, TipTarget], TipFit | str]] = {
        "fast fit": fast_tip_fit,
        "model fit": fit_tip,
        "image fit": fit_tip_image,
    }
    fit = fitters[method](gray, blob, target)
    if isinstance(fit, str):
        return TipDetection.none(fit, method)
    h, w = gray.shape
    if fit.blur_px > max_blur_px:
        return TipDetection.none(
            f"too defocused: the tip is blurred by {fit.blur_px:.1f} px (at most {max_blur_px:g})",
            method,
        )
    if fit.contrast < 0.05:
        return TipDetection.none(
            f"no tool in view (the outline's contrast is {fit.contrast:.2f})", method
        )
    moved = float(np.linalg.norm(fit.apex_px - blob.tip_px))
    reach = 12.0 + 3 * fit.blur_px
    step = fit.apex_px - blob.tip_px
    aside = abs(float(step[0] * blob.axis[1] - step[1] * blob.axis[0]))
    if method in _FOLLOW_PX and aside <= reach:
        reach = _FOLLOW_PX[method]  # it may follow a faint end far along the coarse axis
    if moved > reach or not np.all(np.isfinite(fit.cov_px)):
        return TipDetection.none(f"the {method} did not settle (it moved {moved:.0f} px)", method)
    ax, ay = fit.apex_px
    if not (0.0 <= ax <= w - 1.0 and 0.0 <= ay <= h - 1.0):
        return TipDetection.none("the tip is out of the field", method)
    return TipDetection(
        True, fit.apex_px, fit.cov_px, fit.axis, fit.vertex_px,
        math.degrees(fit.half_angle_rad), fit.blur_px, method,
    )  # fmt: skip


def detect_tip(
    image: NDArray[np.generic],
    target: TipTarget,
    *,
    roi: tuple[int, int, int, int] | None = None,
    max_blur_px: float = MAX_BLUR_PX,
    method: str | None = None,
) -> TipDetection:
    """Find a tool's tip in an image by the fast fit, the model fit or the image fit.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        8 or 16 bit, or float; colour in OpenCV's BGR order.
    target : TipTarget
    roi : (x0, y0, x1, y1), optional
        Search only this box (end exclusive); positions are still in whole-image pixels.
    max_blur_px : float
        A tip blurred more than this (Gaussian sigma, px) is too defocused.
    method : {"fast fit", "model fit", "image fit"}, optional
        By default :func:`default_method` of the target.

    Returns
    -------
    TipDetection
        ``found=False`` with a reason when there is no tip to be located.
    """
    method = default_method(target) if method is None else method
    if method not in TIP_METHODS:
        raise InputError(f"method: expected one of {', '.join(TIP_METHODS)}, got {method!r}")
    cropped = _crop(image, roi)
    if isinstance(cropped, str):
        return TipDetection.none(cropped, method)
    gray, x0, y0 = cropped
    blob = coarse_tool(gray) if method == "fast fit" else find_tool(gray)
    if isinstance(blob, str):
        return TipDetection.none(blob, method)
    det = _fitted(gray, blob, target, method, max_blur_px)
    if not det.found and method == "fast fit":
        # the halved image's coarse tip may be far off (debris joined to the tool, a faint
        # end): once more from the whole image's
        again = find_tool(gray)
        if not isinstance(again, str):
            retry = _fitted(gray, again, target, method, max_blur_px)
            det = retry if retry.found else det
    return det.shifted(x0, y0) if (x0 or y0) else det
