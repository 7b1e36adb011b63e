"""A calibrated tip as Micro-Manager stages (pymmcore-plus ``unicore``): X-Y and Z in {G}.

Any Micro-Manager or pymmcore-plus acquisition addresses stages; :func:`register_tip_stage`
loads two pure-Python stage devices into a ``UniMMCore`` that move a calibrated
manipulator's tip in calibrated micrometres of {G}: ``TipXY`` sets x and y, ``TipZ`` sets z,
each keeping the other coordinates of the last target. What moves the tip is a
:class:`TipMover` (``microcal.workflows.tip_stage`` makes one from a rig and its
calibration: the compensator's joints, checked against the soft limits before anything
moves), so this module knows Micro-Manager and nothing of calibrations.
"""

from __future__ import annotations

import threading
from typing import Any, Protocol

import numpy as np
from pymmcore_plus.experimental.unicore import StageDevice, XYStageDevice

from .._validation import FloatArray

__all__ = ["TipMover", "TipXYStage", "TipZStage", "register_tip_stage"]


class TipMover(Protocol):
    """What the stage devices drive: a tip addressed in {G}."""

    def move_tip_um(self, p_um: FloatArray) -> None:
        """Start moving the tip to ``p_um`` (3,) in {G} (raises before anything moves if it
        cannot go there)."""

    def tip_um(self) -> FloatArray:
        """Where the calibration puts the tip now, (3,) µm in {G}."""

    def busy(self) -> bool:
        """True while the device moves."""

    def stop(self) -> None:
        """Stop now."""

    def close(self) -> None:
        """Release the devices."""


class _SharedTip:
    """The two stages' common target (x, y, z), initialised where the tip is."""

    def __init__(self, mover: TipMover) -> None:
        self.mover = mover
        self.target: FloatArray = np.asarray(mover.tip_um(), dtype=np.float64).copy()
        self.users = 2
        self.lock = threading.Lock()

    def go(self, axes: slice, values: list[float]) -> None:
        with self.lock:
            target = self.target.copy()
            target[axes] = values
            self.mover.move_tip_um(target)  # refused: the target stays as it was
            self.target = target

    def release(self) -> None:
        with self.lock:
            self.users -= 1
            if self.users == 0:
                self.mover.close()


class _TipDevice:
    """What both stages do alike: the shared tip's motion state, stop, no home, release."""

    def __init__(self, shared: _SharedTip) -> None:
        super().__init__()
        self._tip = shared

    def busy(self) -> bool:
        return self._tip.mover.busy()

    def stop(self) -> None:
        self._tip.mover.stop()

    def home(self) -> None:
        raise NotImplementedError("the calibrated tip has no home; set a position in {G}")

    def shutdown(self) -> None:
        self._tip.release()


class TipXYStage(_TipDevice, XYStageDevice):
    """x and y of the tip in {G}, µm."""

    def set_position_um(self, x: float, y: float) -> None:
        self._tip.go(slice(0, 2), [float(x), float(y)])

    def get_position_um(self) -> tuple[float, float]:
        p = self._tip.mover.tip_um()
        return float(p[0]), float(p[1])

    def set_origin_x(self) -> None:
        raise NotImplementedError("the calibrated tip's origin is {G}'s; it cannot be moved")

    def set_origin_y(self) -> None:
        raise NotImplementedError("the calibrated tip's origin is {G}'s; it cannot be moved")


class TipZStage(_TipDevice, StageDevice):
    """z of the tip in {G}, µm."""

    def set_position_um(self, val: float) -> None:
        self._tip.go(slice(2, 3), [float(val)])

    def get_position_um(self) -> float:
        return float(self._tip.mover.tip_um()[2])

    def set_origin(self) -> None:
        raise NotImplementedError("the calibrated tip's origin is {G}'s; it cannot be moved")


def register_tip_stage(
    core: Any, mover: TipMover, xy_label: str = "TipXY", z_label: str = "TipZ"
) -> tuple[TipXYStage, TipZStage]:
    """Load the tip's two stages into a ``UniMMCore`` (``core.loadPyDevice``); unloading
    both (``core.unloadAllDevices()``) closes ``mover``."""
    shared = _SharedTip(mover)
    xy, z = TipXYStage(shared), TipZStage(shared)
    core.loadPyDevice(xy_label, xy)
    core.loadPyDevice(z_label, z)
    return xy, z
