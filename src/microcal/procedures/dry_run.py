"""The dry run of an acquisition: every device answers, one frame each, the plan fits."""

from __future__ import annotations

from collections.abc import Mapping

from ..devices.base import Camera, Manipulator
from ..errors import DeviceError
from ..vision.detect import detect
from ..vision.targets import Target
from ..vision.tip import detect_tip
from ..vision.tip_target import TipTarget
from .acquisition import Frame, grab_retrying
from .planning import RunPlan

__all__ = ["dry_run"]


def dry_run(
    manipulator: Manipulator,
    cameras: Mapping[str, Camera],
    board: Target | TipTarget,
    plan: RunPlan,
    description: Mapping[str, str] | None = None,
) -> list[str]:
    """Check a rig before a run without moving anything; the lines to show the user.

    Reads the manipulator's position and state, grabs one frame per camera (checking its
    size against the camera's and looking for the board) and states that the plan's commands
    lie within the soft limits (:func:`~microcal.procedures.planning.plan_run` checked them).

    Raises
    ------
    DeviceError
        A device that does not answer, or a camera whose frames are not the size it reports.
    """
    lines = [f"{what}: {text}" for what, text in (description or {}).items()]
    p = manipulator.position_um()
    where = ", ".join(f"{a} {v:.3f}" for a, v in zip(manipulator.axes, p, strict=True))
    axes_limits = zip(manipulator.axes, manipulator.limits_um, strict=True)
    limits = ", ".join(f"{a} [{lo:g}, {hi:g}]" for a, (lo, hi) in axes_limits)
    state = "moving" if manipulator.is_moving() else "still"
    lines.append(f"manipulator at {where} µm, {state}; limits {limits} µm")
    for name, cam in cameras.items():
        frame = grab_checked(cam, f"camera {name}")
        h, w = frame.shape[:2]
        if isinstance(board, TipTarget):  # a tool's tip instead of a board
            tip = detect_tip(frame, board)
            seen = "tip found" if tip.found else f"tip not found ({tip.reason})"
        else:
            found = detect(frame, board)
            seen = "board found" if found.found else f"board not found ({found.reason})"
        lines.append(f"camera {name}: {w} x {h} px, {frame.dtype}, "
                     f"mean {float(frame.mean()):.1f}; {seen}")  # fmt: skip
    lines.append(f"design {plan.kind}: {plan.poses} poses, all within the soft limits")
    lines.append("dry run: nothing moved, nothing written")
    return lines


def grab_checked(camera: Camera, label: str) -> Frame:
    """One frame (grabbed again after a dropped frame or a timeout), its size checked against
    the size the camera reports; ``label`` names the camera in the error."""
    frame = grab_retrying(camera, retries=2)
    h, w = frame.shape[:2]
    if (w, h) != tuple(camera.sensor_size_px):
        raise DeviceError(
            f"{label}: frame is {w} x {h} px but the camera reports "
            f"{camera.sensor_size_px[0]} x {camera.sensor_size_px[1]}"
        )
    return frame
