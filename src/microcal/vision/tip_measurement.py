"""A tool's tip in one camera's frames of a pose, for the 3D measurement.

The tip is found in every frame (:func:`~microcal.vision.tip.detect_tip`; after the first
frame, in a box around it, since the tool stands still during a pose), its apex undistorted
into the camera's ideal pixels, as the board's virtual point is: the cameras' apexes are then
triangulated like virtual points. The apex is the image of the tip point on the tool's axis
(``docs/conventions.md``), so every camera sees the same 3D point.

When the spec gives the tool's size (``tip:needle:20:5``, ``tip:pipette:10:1``), the tip
point's image is taken from where the taper's edges meet (the vertex, which the outline fixes
far better than the end when the end is a fraction of a pixel) moved along the axis by the
end's radius ``rho`` in pixels over ``sin(beta)``, ``beta`` half the angle between the edges
in the image: a cone of half-angle ``alpha`` seen at ``phi`` from its axis shows
``sin(beta) = sin(alpha) / sin(phi)``, and its tip point lies ``r / sin(alpha)`` (a sphere's
centre) or ``r / tan(alpha)`` (a ring's) from the vertex, so its image lies ``rho / sin(beta)``
(times ``cos(alpha)`` for the ring) from the vertex's. The pixel's size is the camera's at
{G}'s origin (the calibration target's; within a few percent across a manipulator's travel).
That vertex is the model fit's (:mod:`~microcal.vision.tip_fit`), which this path uses
whatever the tool's default method: on coarse cameras, where the end is a fraction of a
pixel, the image fit's vertex is no better (``docs/vision.md``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..geometry import AnyCamera
from .tip import TipDetection, detect_tip
from .tip_target import TipTarget

__all__ = ["TIP_BOX_HALF_PX", "takes_vertex_path", "tip_of_frames"]

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
    method = "model fit" if takes_vertex_path(target) else None
    for image in frames:
        if first is not None:
            c = np.round(first[0]).astype(int)
            roi = (int(c[0]) - TIP_BOX_HALF_PX, int(c[1]) - TIP_BOX_HALF_PX,
                   int(c[0]) + TIP_BOX_HALF_PX, int(c[1]) + TIP_BOX_HALF_PX)  # fmt: skip
        det = detect_tip(image, target, roi=roi, method=method) if roi is not None else None
        if det is None or not det.found:
            det = detect_tip(image, target, method=method)
        if not det.found:
            return det.reason
        apexes.append(model.undistort_px(tip_point_px(det, target, model))[0])
        covs.append(det.cov_px)
        if first is None:
            first = det.apex_px.reshape(1, 2)
    assert first is not None
    return np.array(apexes), np.mean(covs, axis=0), first


def takes_vertex_path(target: TipTarget) -> bool:
    """Whether the tip point is taken from the model fit's vertex (a needle or a pipette whose
    spec gives its taper and size)."""
    return target.kind in ("needle", "pipette") and target.taper_deg > 0 and target.tip_um > 0


def tip_point_px(det: TipDetection, target: TipTarget, model: AnyCamera) -> FloatArray:
    """The tip point's image (2,): the detection's apex, or for a needle or a pipette whose
    spec gives its taper and size, the vertex moved along the axis by the end's radius (see
    the module docstring)."""
    beta = math.radians(det.half_angle_deg)
    usable = np.all(np.isfinite(det.vertex_px)) and 0 < beta < math.pi / 2
    if not takes_vertex_path(target) or not usable:
        return det.apex_px
    J = np.asarray(model.project_jacobian(np.zeros(3), distort=False), dtype=np.float64)
    s = np.linalg.svd(J.reshape(2, 3), compute_uv=False)
    rho_px = 0.5 * target.tip_um * math.sqrt(s[0] * s[1])
    ring = math.cos(target.half_angle_rad) if target.kind == "pipette" else 1.0
    out: FloatArray = det.vertex_px + det.axis * (rho_px * ring / math.sin(beta))
    return out
