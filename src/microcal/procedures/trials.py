"""The trial steps every evaluation test shares: command a pose through a condition, settle,
and measure it by each source (the cameras, and on the simulator the ground truth).

``procedures.evaluation`` (pose accuracy, multi-directional, decoupling) and
``procedures.iso_tests`` (distance, stabilisation, drift) both build on them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from .._validation import FloatArray
from ..control.feedforward import FeedForward
from ..devices.base import Clock, Manipulator
from ..errors import InputError

__all__ = [
    "Command",
    "PositionProbe",
    "aimed_poses_um",
    "commanders",
    "measure_by_sources",
    "settle",
    "sources",
    "visit",
]


class PositionProbe(Protocol):
    """What measures the end-effector for an evaluation (a :class:`VisionProbe`, or on the
    simulator a projection of the truth)."""

    def measure(self, d_um: FloatArray) -> FloatArray:
        """Position in {G} now, (3,) µm (NaN when it cannot be measured); ``d_um`` are the
        joints commanded, a hint for where to look."""
        ...


Command = Callable[[FloatArray], FloatArray]  # displacement from home -> joints commanded


def _uncompensated(manipulator: Manipulator) -> Command:
    def command(rel: FloatArray) -> FloatArray:
        manipulator.move_to_um(rel)
        return rel

    return command


def _compensated(ff: FeedForward) -> Command:
    home: list[FloatArray] = []  # the model's home, taken once per condition

    def command(rel: FloatArray) -> FloatArray:
        if not home:
            home.append(ff.home_um())
        return ff.move_to_position_um(home[0] + rel)

    return command


def commanders(
    manipulator: Manipulator, conditions: dict[str, FeedForward | None]
) -> dict[str, Command]:
    return {
        name: _uncompensated(manipulator) if ff is None else _compensated(ff)
        for name, ff in conditions.items()
    }


def sources(probe: PositionProbe | None, truth: Callable[[], FloatArray] | None) -> list[str]:
    """The sources that measure: ``vision`` (the probe), then ``truth``."""
    if probe is None and truth is None:
        raise InputError(
            "evaluation: nothing measures the end-effector (no cameras, no ground truth)"
        )
    return [name for name, by in (("vision", probe), ("truth", truth)) if by is not None]


def measure_by_sources(
    probe: PositionProbe | None, truth: Callable[[], FloatArray] | None, d_um: FloatArray
) -> dict[str, FloatArray]:
    got = {}
    if probe is not None:
        got["vision"] = probe.measure(d_um)
    if truth is not None:
        got["truth"] = truth()
    return got


def settle(manipulator: Manipulator, clock: Clock, settle_s: float) -> None:
    manipulator.wait_until_stopped(clock)
    clock.sleep(settle_s)


def visit(
    command: Command,
    rel_um: FloatArray,
    manipulator: Manipulator,
    clock: Clock,
    settle_s: float,
    probe: PositionProbe | None,
    truth: Callable[[], FloatArray] | None,
) -> dict[str, FloatArray]:
    """Command a displacement from home, settle, and measure: the position by each source."""
    d = command(rel_um)
    settle(manipulator, clock, settle_s)
    return measure_by_sources(probe, truth, d)


def aimed_poses_um(ff: FeedForward | None, poses_um: FloatArray) -> FloatArray:
    """The displacements from home a condition aims at for ``poses_um``, (N, 3) µm.

    The poses themselves, except for a compensated device with held joints (an X-Y
    positioner): it reaches only a surface, so each pose is moved to the nearest point of
    that surface by its model (its command pose in the sense of ISO 9283: one it can attain).
    """
    if ff is None or not ff.model.held_um:
        return np.asarray(poses_um, dtype=np.float64)
    home = ff.home_um()
    return np.array([ff.aim_um(home + p) - home for p in np.asarray(poses_um, float)])
