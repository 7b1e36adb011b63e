"""Epipolar curves: where a pixel of one view can lie in another, lens distortion included.

A click in one camera is a ray in {G}; every point of that ray projects into another camera
on one curve (a straight line without distortion). The station's page draws that curve so
that a second click on it fixes the depth of the first.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from .camera_protocol import CameraModelProtocol

__all__ = ["epipolar_curve_px"]


def epipolar_curve_px(
    source: CameraModelProtocol,
    q_px: ArrayLike,
    other: CameraModelProtocol,
    near_um: ArrayLike,
    half_length_um: float = 20000.0,
    samples: int = 64,
) -> FloatArray:
    """The pixels of ``other`` that the ray of pixel ``q_px`` of ``source`` projects to.

    Parameters
    ----------
    source, other : camera model
        Two calibrated cameras in the same {G}.
    q_px : (2,) float
        An observed pixel of ``source`` (distortion included).
    near_um : (3,) float
        A point in {G} near where the target may be (the tip, the workspace's centre): the
        stretch of the ray sampled is centred on the ray's point closest to it.
    half_length_um : float
        Half the length of that stretch, µm.
    samples : int
        Points along the stretch (>= 2).

    Returns
    -------
    curve_px : (M, 2) float
        The samples that land inside ``other``'s image, in order along the ray (M may be 0:
        the ray does not cross the other view).
    """
    q = as_array(q_px, "q_px", (2,))
    origin, direction = source.back_project(q[None, :])
    near = as_array(near_um, "near_um", (3,))
    centre = float((near - origin[0]) @ direction[0])
    s = centre + np.linspace(-half_length_um, half_length_um, max(int(samples), 2))
    points = origin[0] + s[:, None] * direction[0]
    curve = other.project(points)
    w, h = other.image_size_px
    inside = (
        np.isfinite(curve).all(axis=1)
        & (curve[:, 0] >= -0.5)
        & (curve[:, 0] <= w - 0.5)
        & (curve[:, 1] >= -0.5)
        & (curve[:, 1] <= h - 0.5)
    )
    out: FloatArray = curve[inside]
    return out
