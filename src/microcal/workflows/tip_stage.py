"""A calibrated tip as Micro-Manager stages: the loader a pymmcore-plus core calls.

``open_core(python_devices="microcal.workflows.tip_stage:load", options={"rig": "sim",
"calibration": "calibration.json"})`` (or a rig file's ``[micromanager]`` table naming the
same) loads ``TipXY`` and ``TipZ`` (:mod:`microcal.devices.mm_tip_stage`): setting their
positions sends the calibrated tip to that point of {G} through the compensator, open loop,
every joint checked against the soft limits before anything moves; the call returns when the
device has stopped.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from .._validation import FloatArray
from ..control.feedforward import FeedForward, extra_inputs_reader
from .station import CalibratedRig, open_calibrated_rig

__all__ = ["CompensatedTip", "load"]


class CompensatedTip:
    """A :class:`~microcal.devices.mm_tip_stage.TipMover` of a calibrated rig."""

    def __init__(self, calibrated: CalibratedRig) -> None:
        self.calibrated = calibrated
        rig, entry = calibrated.device, calibrated.entry
        model = entry.model
        method: Literal["optimal", "matrix"] = "optimal" if model.kind == "polynomial" else "matrix"
        extra = extra_inputs_reader(model, rig.sensors)
        self._ff = FeedForward(rig.manipulator, model, method, extra, rig.clock)

    def move_tip_um(self, p_um: FloatArray) -> None:
        """Move and wait until the device has stopped (on the rig's clock: a simulated rig's
        time passes only while something waits on it)."""
        self._ff.move_to_position_um(p_um)
        rig = self.calibrated.device
        rig.manipulator.wait_until_stopped(rig.clock)

    def tip_um(self) -> FloatArray:
        d = self.calibrated.device.manipulator.position_um()
        out: FloatArray = np.asarray(self.calibrated.entry.predict_um(d[None, :])[0])
        return out

    def busy(self) -> bool:
        return self.calibrated.device.manipulator.is_moving()

    def stop(self) -> None:
        self.calibrated.device.manipulator.stop()

    def close(self) -> None:
        self.calibrated.opened.close()


def load(
    core: Any,
    rig: str = "sim",
    calibration: str = "calibration.json",
    manipulator: str | None = None,
    seed: int | None = None,
    xy_label: str = "TipXY",
    z_label: str = "TipZ",
) -> None:
    """Open the rig with its calibration and load the tip's stages into ``core``.

    Raises
    ------
    InputError, FormatError, DeviceError
        As ``microcal goto``; nothing is left open.
    """
    from ..devices.mm_tip_stage import register_tip_stage

    calibrated = open_calibrated_rig(rig, calibration, manipulator=manipulator, seed=seed)
    try:
        register_tip_stage(core, CompensatedTip(calibrated), xy_label, z_label)
    except BaseException:
        calibrated.opened.close()
        raise
