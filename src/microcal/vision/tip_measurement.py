"""A tool's tip in one camera's frames of a pose, for the 3D measurement.

The tip is found in every frame (:func:`~microcal.vision.tip.detect_tip`; after the first
frame, in a box around it, since the tool stands still during a pose), its apex undistorted
into the camera's ideal pixels, as the board's virtual point is: the cameras' apexes are then
triangulated like virtual points. The apex is the image of the tip point on the tool's axis
(``docs/conventions.md``), so every camera sees the same 3D point.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..geometry import AnyCamera
from .tip import detect_tip
from .tip_target import TipTarget

__all__ = ["TIP_BOX_HALF_PX", "tip_of_frames"]

#: Half the side of the box the tip is searched in after the first frame, px.
TIP_BOX_HALF_PX = 64


def tip_of_frames(
    frames: Sequence[NDArray[np.generic]],
    target: TipTarget,
    model: AnyCamera,
    roi: tuple[int, int, int, int] | None,
) -> tuple[FloatArray, FloatArray, FloatArray] | str:
    """Apexes (k, 2) in ideal pixels, their mean covariance (2, 2), and the first frame's apex
    (1, 2) in the image (for the next search box); or the reason the tip was not found."""
    apexes, covs, first = [], [], None
    for image in frames:
        if first is not None:
            c = np.round(first[0]).astype(int)
            roi = (int(c[0]) - TIP_BOX_HALF_PX, int(c[1]) - TIP_BOX_HALF_PX,
                   int(c[0]) + TIP_BOX_HALF_PX, int(c[1]) + TIP_BOX_HALF_PX)  # fmt: skip
        det = detect_tip(image, target, roi=roi) if roi is not None else None
        if det is None or not det.found:
            det = detect_tip(image, target)
        if not det.found:
            return det.reason
        apexes.append(model.undistort_px(det.apex_px)[0])
        covs.append(det.cov_px)
        if first is None:
            first = det.apex_px.reshape(1, 2)
    assert first is not None
    return np.array(apexes), np.mean(covs, axis=0), first
