"""The control conditions an evaluation compares: uncalibrated, matrix and optimal."""

from __future__ import annotations

from ..devices.base import Manipulator
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from .feedforward import FeedForward

__all__ = ["open_loop_conditions"]


def open_loop_conditions(
    manipulator: Manipulator, calibration: ManipulatorCalibration
) -> dict[str, FeedForward | None]:
    """The open-loop conditions of thesis 5.3 for one calibrated manipulator.

    ``uncalibrated`` (None: joints commanded as given), ``matrix`` (the matrix compensator of
    the matrix model, Eq 4.16, or of the model itself when it is a matrix model) and, for a
    polynomial model, ``optimal`` (Eq 4.17-4.19).
    """
    model = calibration.model
    out: dict[str, FeedForward | None] = {
        "uncalibrated": None,
        "matrix": FeedForward(manipulator, calibration.matrix_model or model, "matrix"),
    }
    if model.kind == "polynomial":
        out["optimal"] = FeedForward(manipulator, model, "optimal")
    return out
