"""A pixel of one camera and a depth along its optical axis: a point in {G}.

With one camera a click is a ray; the plane at a given depth from the camera (its plane of
best focus, moved by an offset) cuts the ray in one point. Its covariance follows from the
pixel's and the depth's uncertainty, to first order.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from .camera_kinds import AnyCamera
from .camera_model import CameraModel

__all__ = ["point_at_depth_um", "point_at_depth_with_cov"]

#: Steps of the numerical derivatives: a pixel, a depth.
_STEP_PX = 0.05
_STEP_UM = 1.0


def point_at_depth_um(camera: AnyCamera, q_px: ArrayLike, depth_um: float) -> FloatArray:
    """The point of {G} (3,) µm that pixel ``q_px`` (2,) of ``camera`` (distortion included)
    sees at ``depth_um`` along the camera's optical axis (``camera.depth_um`` of it); NaN where
    the ray does not reach that depth (parallel to the plane, or behind the camera)."""
    q = as_array(q_px, "q_px", (2,))
    origin, direction = camera.back_project(q[None, :])
    o, v = origin[0], direction[0]
    d0 = float(camera.depth_um(o[None, :])[0])
    rate = float(camera.depth_um((o + v)[None, :])[0]) - d0  # depth per µm along the ray
    if not np.isfinite(rate) or abs(rate) < 1e-12:
        return np.full(3, np.nan)
    s = (float(depth_um) - d0) / rate
    if s < 0 and isinstance(camera, CameraModel):  # a pinhole camera sees only in front of it
        return np.full(3, np.nan)
    out: FloatArray = o + s * v
    return out


def point_at_depth_with_cov(
    camera: AnyCamera,
    q_px: ArrayLike,
    depth_um: float,
    cov_px2: ArrayLike,
    depth_var_um2: float,
) -> tuple[FloatArray, FloatArray]:
    """:func:`point_at_depth_um` and its covariance (3, 3) µm² from the pixel's covariance
    ``cov_px2`` (2, 2) and the depth's variance (µm²), independent, to first order."""
    q = as_array(q_px, "q_px", (2,))
    cov_q = as_array(cov_px2, "cov_px2", (2, 2))
    p = point_at_depth_um(camera, q, depth_um)
    if not np.all(np.isfinite(p)):
        return p, np.full((3, 3), np.nan)
    J = np.empty((3, 3))
    for i in range(2):
        dq = np.zeros(2)
        dq[i] = _STEP_PX
        J[:, i] = (
            point_at_depth_um(camera, q + dq, depth_um)
            - point_at_depth_um(camera, q - dq, depth_um)
        ) / (2 * _STEP_PX)
    J[:, 2] = (
        point_at_depth_um(camera, q, depth_um + _STEP_UM)
        - point_at_depth_um(camera, q, depth_um - _STEP_UM)
    ) / (2 * _STEP_UM)
    inputs = np.zeros((3, 3))
    inputs[:2, :2] = cov_q
    inputs[2, 2] = float(depth_var_um2)
    cov: FloatArray = J @ inputs @ J.T
    return p, 0.5 * (cov + cov.T)
