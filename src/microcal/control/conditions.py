"""The control conditions an evaluation compares: uncalibrated, matrix and optimal."""

from __future__ import annotations

from collections.abc import Callable

from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..devices.base import Clock, Manipulator
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from .closed_loop import ClosedLoop, Measure
from .feedforward import FeedForward
from .visual_servo import ServoConfig

__all__ = ["closed_loop_condition", "open_loop_conditions"]


def open_loop_conditions(
    manipulator: Manipulator,
    calibration: ManipulatorCalibration,
    extra: Callable[[], ArrayLike] | None = None,
    clock: Clock | None = None,
) -> dict[str, FeedForward | None]:
    """The open-loop conditions of thesis 5.3 for one calibrated manipulator.

    ``uncalibrated`` (None: joints commanded as given), ``matrix`` (the matrix compensator of
    the matrix model, Eq 4.16, or of the model itself when it is a matrix model) and, for a
    polynomial model, ``optimal`` (Eq 4.17-4.19). ``extra`` reads the values of the model's
    extra inputs (the temperature) at every move; ``clock`` is needed by a model with
    approach-direction terms (see :class:`FeedForward`).
    """
    model = calibration.model
    matrix = calibration.matrix_model or model
    matrix_extra = extra if matrix.extra_inputs else None
    out: dict[str, FeedForward | None] = {
        "uncalibrated": None,
        "matrix": FeedForward(manipulator, matrix, "matrix", matrix_extra),
    }
    if model.kind == "polynomial":
        out["optimal"] = FeedForward(manipulator, model, "optimal", extra, clock)
    return out


def closed_loop_condition(
    manipulator: Manipulator,
    calibration: ManipulatorCalibration,
    measure: Measure,
    clock: Clock,
    extra: Callable[[], ArrayLike] | None = None,
    config: ServoConfig | None = None,
    settle_s: float = 1.0,
    truth: Callable[[], FloatArray] | None = None,
) -> ClosedLoop:
    """The ``closed_loop`` condition: the optimal compensator's move (the matrix one for a
    matrix model), then visual servoing to the target (:class:`ClosedLoop`)."""
    return ClosedLoop(manipulator, calibration.model, measure, clock, extra, config, settle_s,
                      truth=truth)  # fmt: skip
