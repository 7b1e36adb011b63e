"""One target's features found in one image (:class:`Detection`), and the homography check
of their quality; shared by every detector."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from .targets import Target

__all__ = ["Detection", "homography_rms_px"]


@dataclass(frozen=True)
class Detection:
    """Features of one target found in one image.

    Attributes
    ----------
    found : bool
    ids : (N,) int
        Indices into ``target.points_um()``.
    q_px : (N, 2) float
        Pixel positions (OpenCV convention), in the whole image's coordinates.
    quality_px : float
        RMS residual of a plane homography through the features (NaN if not found).
    reason : str
        Why nothing was found ("" when found).
    method : str
        Which detector found it.
    """

    found: bool
    ids: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, dtype=np.intp))
    q_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    quality_px: float = float("nan")
    reason: str = ""
    method: str = ""

    @classmethod
    def none(cls, reason: str) -> Detection:
        """Nothing found, for ``reason``."""
        return cls(False, reason=reason)


def homography_rms_px(target: Target, ids: NDArray[np.intp], q: FloatArray) -> float:
    """RMS residual, px, of a plane homography from the target's points ``ids`` to ``q``
    (N, 2); NaN for fewer than 4 points or a degenerate fit."""
    if len(ids) < 4:
        return float("nan")
    plane = target.points_um()[ids, :2]
    H: Any = cv2.findHomography(plane, q, 0)[0]  # None when degenerate (the stubs omit it)
    if H is None:
        return float("nan")
    proj = cv2.perspectiveTransform(plane.reshape(-1, 1, 2), H).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum((proj - q) ** 2, axis=1))))
