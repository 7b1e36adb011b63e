"""The dry run of a one-camera acquisition: every device answers, one frame, the volume fits.

Nothing moves: the manipulator's and the microscope's positions are read, one whole frame
is grabbed (its size checked against the camera's, the tip looked for in it by the tip
detector: a note, not a refusal, since a pipette's heavily blurred shank can hide it from
one frame; the run itself finds it by a focus sweep), and the working
volume's corners, taken to the joints by the nominal axes from where the joints are, are
checked against the manipulator's soft limits.
"""

from __future__ import annotations

import itertools

import numpy as np

from .._validation import FloatArray
from ..devices.base import Camera, Manipulator
from ..errors import InputError
from ..vision.tip import detect_tip
from ..vision.tip_target import TipTarget
from .dry_run import grab_checked

__all__ = ["one_camera_dry_run"]


def one_camera_dry_run(
    manipulator: Manipulator,
    microscope: Manipulator,
    camera: Camera,
    tip: TipTarget,
    volume_half_um: FloatArray,
    nominal_um_per_um: FloatArray,
    poses: int,
) -> list[str]:
    """Check a one-camera rig before a run without moving anything; the lines to show.

    Parameters
    ----------
    manipulator, microscope : Manipulator
        The pipette's manipulator; the X-Y stage and focus (joints x, y, z).
    camera : Camera
    tip : TipTarget
    volume_half_um : (3,) float
        The working volume's half sizes in {M}, µm.
    nominal_um_per_um : (3, 3) float
        The tip's move in {M} per µm of each joint, as the rig is built.
    poses : int

    Raises
    ------
    DeviceError
        A device that does not answer, or a frame not of the camera's size.
    InputError
        A working volume that reaches beyond the manipulator's soft limits from here.
    """
    p = manipulator.position_um()
    where = ", ".join(f"{a} {v:.3f}" for a, v in zip(manipulator.axes, p, strict=True))
    state = "moving" if manipulator.is_moving() else "still"
    lines = [f"manipulator at {where} µm, {state}"]
    s = microscope.position_um()
    lines.append(f"microscope: stage x {s[0]:.3f}, y {s[1]:.3f} µm, focus {s[2]:.3f} µm")
    frame = grab_checked(camera, "camera")
    h, w = frame.shape[:2]
    found = detect_tip(frame, tip)
    seen = (f"tip found at ({found.apex_px[0]:.1f}, {found.apex_px[1]:.1f}) px" if found.found
            else f"tip not detected in this one frame ({found.reason}), which is common for a "
                 "pipette's fine tip in one frame: the run finds it by a focus sweep, so have it "
                 "in focus at the field's centre")  # fmt: skip
    lines.append(f"camera: {w} x {h} px, {frame.dtype}, mean {float(frame.mean()):.1f}; {seen}")
    half = np.asarray(volume_half_um, dtype=np.float64)
    corners = np.array(list(itertools.product(*[(-v, v) for v in half])))
    joints = np.asarray(p, dtype=np.float64) + np.linalg.solve(nominal_um_per_um, corners.T).T
    for j, (axis, (lo, hi)) in enumerate(zip(manipulator.axes, manipulator.limits_um, strict=True)):
        a, b = float(joints[:, j].min()), float(joints[:, j].max())
        if a < lo or b > hi:
            raise InputError(
                f"--volume-um: joint {axis} would go over [{a:.1f}, {b:.1f}] µm, beyond its "
                f"soft limits [{lo:g}, {hi:g}]; move the tip or make the volume smaller"
            )
    size = " x ".join(f"{2 * v:g}" for v in half)
    lines.append(f"design: {poses} poses in {size} µm around the tip, within the soft limits")
    return lines
