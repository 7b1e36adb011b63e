"""The tip in 3D at one pose of a one-camera rig (a camera on a focus drive).

:func:`measure_tip_one_camera` is the measurement a one-camera acquisition calls per pose:
on two callables, ``move_focus(z_um)`` and ``grab() -> frame``, it finds the tip's depth
from focus (a focus sweep, or one frame against the tool's reference stack; see
:mod:`microcal.vision.focus_depth`) and takes the tip's image position from the same
measurement (the sweep's profile along the tool, or the stack's alignment). The result is
one point ``(x, y, z)``: x, y the tip's image in µm of the image plane (pixels times the
pixel size at the sample), z the focus drive's reading with the tip in focus, with their
joint 3 x 3 covariance, the part of it every pose measured with the same stack shares,
and the cost in frames and seconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray, check_number
from ..errors import InputError
from ..vision.focus_depth import (
    STACK_ABOVE_UM,
    DepthEstimate,
    Frame,
    ReferenceStack,
    depth_by_stack,
    depth_by_sweep,
)

__all__ = ["OneCameraTip", "measure_tip_one_camera"]


@dataclass(frozen=True)
class OneCameraTip:
    """The tip at one pose, from one camera and its focus.

    Attributes
    ----------
    position_um : (3,) float
        x, y: the tip's image times the pixel size at the sample, µm; z: the focus drive's
        reading with the tip in focus, µm.
    cov_um2 : (3, 3) float
        Covariance of :attr:`position_um`, µm^2 (the shared part included).
    shared_cov_um2 : (3, 3) float
        The part of :attr:`cov_um2` every pose measured with the same reference stack
        shares (its anchor and its own focus), µm^2; zero for the sweep.
    depth : DepthEstimate
        The measurement itself (pixels, focus positions, method).
    """

    position_um: FloatArray
    cov_um2: FloatArray
    shared_cov_um2: FloatArray
    depth: DepthEstimate

    @property
    def frames(self) -> int:
        """Frames grabbed."""
        return self.depth.frames

    @property
    def seconds(self) -> float:
        """Time the measurement took on the caller's clock, s."""
        return self.depth.seconds

    @property
    def method(self) -> str:
        """``"sweep"`` or ``"stack"``."""
        return self.depth.method


def _joint(est: DepthEstimate, um_per_px: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position (3,), covariance (3, 3) and its shared part (3, 3) in µm from an estimate."""
    pos = np.array([est.apex_px[0] * um_per_px, est.apex_px[1] * um_per_px, est.z_um])
    cov = np.zeros((3, 3))
    cov[:2, :2] = est.cov_px * um_per_px**2
    cov[2, 2] = est.var_um2
    cov[:2, 2] = cov[2, :2] = est.cov_z_px * um_per_px
    shared = np.zeros((3, 3))
    shared[:2, :2] = est.shared_cov_px * um_per_px**2
    shared[2, 2] = est.shared_var_um2
    return pos, cov, shared


def measure_tip_one_camera(
    move_focus: Callable[[float], object],
    grab: Callable[[], Frame],
    near_px: Sequence[float] | FloatArray,
    prior_um: float,
    um_per_px: float,
    *,
    method: str = "sweep",
    axis_px: Sequence[float] | FloatArray | None = None,
    stack: ReferenceStack | None = None,
    half_px: int = 40,
    frames: int = 13,
    step_um: float = 0.5,
    end_offset_px: float = 0.0,
    above_um: float = STACK_ABOVE_UM,
    clock: Callable[[], float] = time.perf_counter,
) -> OneCameraTip:
    """Measure the tip in 3D at the current pose.

    Parameters
    ----------
    move_focus : callable
        ``move_focus(z_um)`` moves the focus drive to the reading ``z_um`` (approaching
        from the side the rig's backlash wants) and returns when it is there.
    grab : callable
        ``grab()`` returns a frame (an array or a region frame) at the current focus.
    near_px : (2,) float
        Where the tip is expected in the image (within a few px).
    prior_um : float
        Where the tip is expected in focus, µm (within the sweep's half range, or within
        the stack's).
    um_per_px : float
        The pixel size at the sample, µm.
    method : str
        ``"sweep"`` (needs ``axis_px``) or ``"stack"`` (needs ``stack``).
    axis_px : (2,) float, optional
        The tool's direction in the image, tip to shank (the sweep's strips follow it).
    stack : ReferenceStack, optional
        The tool's reference stack, grabbed once during calibration.
    half_px, frames, step_um, end_offset_px : int, int, float, float
        The sweep's region (``2 half_px + 1`` px square around ``near_px``), its frames and
        their spacing, and the tip point's distance behind where the tool begins.
    above_um : float
        The stack method's frame is taken this far above ``prior_um``.
    clock : callable
        The time source the cost is measured on.

    Returns
    -------
    OneCameraTip

    Raises
    ------
    InputError
        An unknown method or a missing input for it, a region outside the field.
    DetectionError
        The tip outside the focus range swept or the stack's, or no tool there.
    """
    check_number("um_per_px", um_per_px, above=0, high=100)
    near = np.asarray(near_px, dtype=np.float64)

    def grab_at_focus(z_um: float) -> Frame:
        move_focus(z_um)
        return grab()

    if method == "sweep":
        if axis_px is None:
            raise InputError("one-camera tip: the sweep needs the tool's image axis (axis_px)")
        x, y = round(float(near[0])), round(float(near[1]))
        region = (x - half_px, y - half_px, x + half_px + 1, y + half_px + 1)
        est = depth_by_sweep(grab_at_focus, region, axis_px, float(prior_um), frames=frames,
                             step_um=step_um, end_offset_px=end_offset_px, clock=clock)  # fmt: skip
    elif method == "stack":
        if stack is None:
            raise InputError("one-camera tip: the stack method needs the tool's reference stack")
        t0 = clock()
        focus = float(prior_um) + float(above_um)
        frame = grab_at_focus(focus)
        est = depth_by_stack(frame, focus, stack, near)
        est = DepthEstimate(est.z_um, est.var_um2, est.frames, clock() - t0 + est.seconds,
                            est.method, est.apex_px, est.cov_px, est.focus_um,
                            est.shared_cov_px, est.shared_var_um2, est.cov_z_px)  # fmt: skip
    else:
        raise InputError(f"one-camera tip: method must be 'sweep' or 'stack', got {method!r}")
    pos, cov, shared = _joint(est, float(um_per_px))
    return OneCameraTip(pos, cov, shared, est)
