"""What a one-camera rig's user knows of the manipulator, as the acquisition takes it.

A patch or injection manipulator's approach axis (its x joint) points along the pipette,
tilted ``approach_deg`` below horizontal, towards ``azimuth_deg`` in the stage's x-y plane
(from +x towards +y of the microscope's frame {M}); its y joint is horizontal across it, its
z joint vertical. These angles, known to a few degrees as the rig is built, give:

- :func:`nominal_axes_um`: the tip's move in {M} per µm of each joint, (3, 3), for where to
  look for the tip after the first steps;
- :func:`tool_finder`: the :class:`~microcal.procedures.one_camera_acquisition.TipFinder` on
  a scope calibration's frame: the pipette's direction in the image (the stage's direction
  through the calibrated map) and how far behind its image's end the tip point lies.
"""

from __future__ import annotations

import math

import numpy as np

from .._validation import FloatArray, check_number
from ..vision.microscope_frame import MicroscopeFrame
from .one_camera_acquisition import TipFinder

__all__ = ["DEFAULT_APPROACH_DEG", "nominal_axes_um", "tool_direction", "tool_finder"]

#: The approach axis's tilt below horizontal when none is given, degrees (a patch rig's).
DEFAULT_APPROACH_DEG = 30.0


def tool_direction(approach_deg: float, azimuth_deg: float) -> FloatArray:
    """The unit direction from the tip towards the shank in {M}, (3,): rising
    ``approach_deg`` above the x-y plane, towards ``azimuth_deg`` (from +x towards +y)."""
    check_number("approach_deg", approach_deg, low=0, high=89)
    check_number("azimuth_deg", azimuth_deg, low=-360, high=360)
    el, az = math.radians(approach_deg), math.radians(azimuth_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def nominal_axes_um(approach_deg: float, azimuth_deg: float = 0.0) -> FloatArray:
    """The tip's move in {M} per µm of each joint as the rig is built, (3, 3) (columns: x
    along the pipette into the sample, y horizontal across it, z vertical)."""
    forward = -tool_direction(approach_deg, azimuth_deg)
    across = np.cross([0.0, 0.0, 1.0], forward)
    across /= np.linalg.norm(across)
    out: FloatArray = np.column_stack([forward, across, [0.0, 0.0, 1.0]])
    return out


def tool_finder(
    frame: MicroscopeFrame, approach_deg: float, azimuth_deg: float, tip_radius_um: float
) -> TipFinder:
    """The tip's finder on ``frame`` for a pipette of ``tip_radius_um`` (its opening's
    radius) tilted as given: its direction in the image, tip to shank, and the tip point's
    distance behind where its image begins (the opening's radius seen at the tilt), px."""
    t = tool_direction(approach_deg, azimuth_deg)
    axis = frame.px_per_um @ t[:2]
    rise = math.sin(math.radians(approach_deg))
    offset = check_number("tip_radius_um", tip_radius_um, low=0) * rise / frame.um_per_px
    return TipFinder(frame, axis / np.linalg.norm(axis), offset)
