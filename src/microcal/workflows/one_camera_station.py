"""A calibrated device on a one-camera rig, as ``goto``, ``evaluate`` and ``check`` use it.

A rig of one camera on a focus drive (its ``microscope``: the X-Y stage and the focus as
joints x, y, z; the simulated ``preset = "patch"``, or a hardware rig naming them) cannot
triangulate: the tip is measured in the microscope's frame {M} of the camera's scope
calibration (``--scope scope.json --objective 40x``), x, y from its image and z from the
focus, by :class:`~microcal.procedures.one_camera_probe.OneCameraTipProbe` (a focus sweep
where the calibration puts the tip for the joints commanded).

What the probe needs besides the scope calibration comes from the device's calibration:

- **the tool's direction in the image**, tip to shank: the opposite of the approach joint's
  direction in {M} (:func:`~microcal.procedures.approach_axis.approach_axis`, the model's
  own), seen through the scope calibration's map; and how far behind the tool's image the
  tip point lies: the opening's radius (the board ``tip:pipette:TAPER:TIP``) seen at the
  axis's tilt;
- **where the joints are counted from**: calibration.json's ``joint_origin_um`` of the
  device (the patch demo counts them from its start pose), so the rig's device is presented
  with its joints shifted by it (:class:`~microcal.devices.shifted_joints.ShiftedJoints`).

On the simulator the ground truth is the tip in the true {M} (the drive's true scale and
tilt), so that AP by truth is in the frame the calibration's targets are in.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..devices.microscope_drive import MicroscopeDrive
from ..devices.rig import Rig
from ..devices.shifted_joints import ShiftedJoints
from ..errors import InputError
from ..formats.scope_file import load_objective, objective_names
from ..kinematics.extra_inputs import default_extra_inputs
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..procedures.approach_axis import approach_axis
from ..procedures.one_camera_acquisition import TipFinder
from ..procedures.one_camera_probe import OneCameraTipProbe
from ..vision.microscope_frame import MicroscopeFrame
from ..vision.tip_target import TipTarget

__all__ = ["OneCameraDevice", "is_one_camera", "one_camera_device"]


def is_one_camera(rig: Rig) -> bool:
    """Whether ``rig`` is a one-camera rig: one camera and a microscope (stage and focus)."""
    return len(rig.cameras) == 1 and rig.microscope is not None


@dataclass(frozen=True)
class OneCameraDevice:
    """The rig with the device as the calibration counts its joints, and its probe.

    Attributes
    ----------
    rig : Rig
        The opened rig with ``manipulator`` the device shifted by ``joint_origin_um`` and
        ``truth`` the tip in the true {M} (None off the simulator); it shares the opened
        rig's devices (close that one).
    probe : OneCameraTipProbe
    objective : str
        The scope calibration's set used.
    joint_origin_um : (3,) float
    """

    rig: Rig
    probe: OneCameraTipProbe
    objective: str
    joint_origin_um: FloatArray


def _objective(scope: str | os.PathLike[str], objective: str | None) -> str:
    """The objective to use: the one named, or the file's only one."""
    if objective is not None:
        return objective
    names = objective_names(scope)
    if len(names) != 1:
        raise InputError(
            f"--objective: {scope} holds {', '.join(names) or 'no objective'}; name the one "
            "the camera looks through (--objective 40x)"
        )
    return names[0]


def _origin(entry: ManipulatorCalibration) -> FloatArray:
    """calibration.json's ``joint_origin_um`` of the device, zero when not recorded."""
    value = entry.extra.get("joint_origin_um")
    if value is None:
        return np.zeros(len(entry.model.joints))
    try:
        origin = np.asarray(value, dtype=np.float64).reshape(len(entry.model.joints))
    except (TypeError, ValueError):
        origin = np.full(len(entry.model.joints), np.nan)
    if not np.all(np.isfinite(origin)):
        raise InputError(
            f"calibration: manipulators.{entry.name}.joint_origin_um: expected "
            f"{len(entry.model.joints)} numbers (µm)"
        )
    return origin


def _scope_truth(rig: Rig) -> Callable[[], FloatArray] | None:
    """The tip in the true {M} on the simulated ``patch`` rig; None elsewhere."""
    from ..sim.patch import PatchRig
    from ..sim.patch_scope import true_frame, truth_in_frame

    patch = getattr(next(iter(rig.cameras.values())), "rig", None)
    return truth_in_frame(patch, true_frame(patch.config)) if isinstance(patch, PatchRig) else None


def _finder(frame: MicroscopeFrame, entry: ManipulatorCalibration, d_um: FloatArray,
            board: object) -> TipFinder:  # fmt: skip
    """The tip's finder: the tool's direction in the image from the model's approach axis,
    the tip point behind the image's end by the opening's radius seen at its tilt."""
    model = entry.model
    extra = default_extra_inputs(model.extra_inputs) if model.extra_inputs else None
    shank = -approach_axis(model, d_um, extra)  # tip towards shank in {M}
    axis_px = frame.px_per_um @ shank[:2]
    if float(np.linalg.norm(axis_px)) < 1e-9:
        raise InputError("the calibration's approach axis is along the optical axis")
    radius = board.tip_um / 2.0 if isinstance(board, TipTarget) else 0.0
    offset = radius * max(float(shank[2]), 0.0) / frame.um_per_px
    return TipFinder(frame, axis_px / np.linalg.norm(axis_px), offset)


def one_camera_device(
    rig: Rig,
    entry: ManipulatorCalibration,
    scope: str | os.PathLike[str] | None,
    objective: str | None,
) -> OneCameraDevice:
    """The device of a one-camera rig and its probe, from the scope calibration's set
    ``objective`` of ``scope`` (the file's only one when None) and the device's calibration
    (module docstring).

    Raises
    ------
    InputError
        No scope file, an objective it does not hold (naming those it does), a set without
        its map, a calibration without an approach axis; one line each.
    """
    if scope is None:
        raise InputError(
            "--scope: a one-camera rig measures the tip in the frame of its camera's scope "
            "calibration; give --scope scope.json --objective NAME (microcal scope-calibrate)"
        )
    name = _objective(scope, objective)
    camera = next(iter(rig.cameras.values()))
    frame = MicroscopeFrame.from_record(load_objective(scope, name), camera.sensor_size_px)
    origin = _origin(entry)
    device = ShiftedJoints(rig.manipulator, origin)
    finder = _finder(frame, entry, device.position_um(), rig.board)
    assert rig.microscope is not None  # a one-camera rig (is_one_camera)
    drive = MicroscopeDrive(rig.microscope, camera, rig.clock)

    def expect(d_um: FloatArray) -> FloatArray:  # approached from below: sides +1
        out: FloatArray = entry.predict_um(np.asarray(d_um, dtype=np.float64))[0]
        return out

    probe = OneCameraTipProbe(finder, drive.move_focus, drive.grab, rig.clock, expect)
    shifted = dataclasses.replace(rig, manipulator=device, truth=_scope_truth(rig))
    return OneCameraDevice(shifted, probe, name, origin)
