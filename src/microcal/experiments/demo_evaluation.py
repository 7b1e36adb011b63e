"""The demo's evaluation (pose accuracy, multi-directional, decoupling) on a simulated platform,
its tests dealt to forked processes.

The open-loop tests command every pose from the test's design alone: where the device goes,
and when, does not depend on what the cameras measure. Only the vision probe's frames cost
time (rendering and searching them). So the tests are cut into units (one test under one
condition), the units are dealt to processes forked from this one, and every process
replays the whole sequence of moves and waits of the sequential run: in its own units it
grabs and searches frames; in the others it only lets the frames' time pass (exposure and
readout per frame and camera, as grabbing them does). Each unit therefore meets the device
as the sequential run does (the same moves, at the same simulated times, with the same
hysteresis and creep behind them), and this process replays the sequence once more, without
frames, so that the platform ends where the sequential run leaves it.

The frames a process leaves out still draw what grabbing them draws
(:meth:`~microcal.sim.camera.SimCamera.pass_frame`: the vibration, the noise's offset and the
fresh noise of the targets' regions), so every frame measured has the noise the sequential
run gives it. What differs from the sequential run is where the probe first looks (each
process's probe learns the board's region from its own measurements), so a board may be
searched in another region: its corners agree to a few thousandths of a pixel. The figures
by ground truth are the same numbers; those by vision the same to that level.

Nothing here reads the simulator's truth beyond what the sequential run does (the ``truth``
source of each test); a test's vision figures come from its frames alone.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .._parallel import can_fork, fork_map
from .._validation import FloatArray
from ..control.feedforward import FeedForward
from ..devices.base import Clock, Manipulator
from ..procedures.evaluation import (
    RunOptions,
    decoupling_path,
    run_decoupling,
    run_multi_directional,
    run_pose_accuracy,
)
from ..procedures.evaluation_figures import BySource, DecouplingFigures, PoseAccuracyFigures
from ..procedures.trials import PositionProbe
from ..sim.camera import SimCamera
from ..vision.probe import VisionProbe

__all__ = ["ClockOnlyProbe", "DemoTests", "deal_units", "run_demo_tests", "units_of"]

PA, DEC = "pose accuracy", "decoupling"
#: One test under one condition: (test, condition).
Unit = tuple[str, str]


class ClockOnlyProbe:
    """Stands in for a :class:`~microcal.vision.probe.VisionProbe` where its frames are not
    wanted: each measurement lets its frames pass (``frames`` per camera, in the probe's
    order: their time and random draws, as grabbing them does) and measures nothing (NaN)."""

    def __init__(self, cameras: Mapping[str, SimCamera], frames: int) -> None:
        self.cameras = cameras
        self.frames = frames

    def measure(self, d_um: FloatArray) -> FloatArray:
        """NaN (3,), once the frames' time has passed."""
        for cam in self.cameras.values():
            for _ in range(self.frames):
                cam.pass_frame()
        return np.full(3, np.nan)


@dataclass
class DemoTests:
    """What the demo's evaluation runs: the tests, their poses and options."""

    manipulator: Manipulator
    clock: Clock
    conditions: dict[str, FeedForward | None]
    poses_um: FloatArray
    cycles: int
    decoupling_samples: int | None  # None: no decoupling test
    options: RunOptions

    def units(self) -> list[Unit]:
        """The units measured by vision, in the order the sequential run meets them."""
        return units_of(list(self.conditions), self.decoupling_samples is not None)

    def weight(self, unit: Unit) -> int:
        """The probe's measurements of a unit (its visits, home included)."""
        if unit[0] == PA:
            return 1 + self.cycles * len(self.poses_um)
        return len(decoupling_path(self.decoupling_samples or 0)[0])

    def run(
        self,
        probe_of: Callable[[Unit], PositionProbe | None],
        progress_of: Callable[[str], Callable[[str, int, int], None] | None],
    ) -> tuple[BySource[PoseAccuracyFigures], BySource[DecouplingFigures] | None]:
        """The whole sequence, as the sequential run makes it: pose accuracy per condition,
        the multi-directional test (by ground truth), decoupling per condition.

        ``probe_of(unit)`` is the probe that measures the unit; ``progress_of(test)`` the
        progress callback of a test (``multi-directional`` included), or None.
        """
        m, clock = self.manipulator, self.clock

        def options(test: str) -> RunOptions:
            return RunOptions(settle_s=self.options["settle_s"], truth=self.options["truth"],
                              progress=progress_of(test))  # fmt: skip

        pa: BySource[PoseAccuracyFigures] = {}
        for name, ff in self.conditions.items():
            probe = probe_of((PA, name))
            _merge(pa, run_pose_accuracy(m, clock, probe, {name: ff}, poses_um=self.poses_um,
                                         cycles=self.cycles, **options(PA)))  # fmt: skip
        vap = run_multi_directional(m, clock, None, self.conditions, poses_um=self.poses_um,
                                    cycles=self.cycles, **options("multi-directional"))  # fmt: skip
        for source, by_condition in vap.items():
            for condition, figures in by_condition.items():
                pa[source][condition] = replace(
                    pa[source][condition], vap_um=figures.vap_um, max_vap_um=figures.max_vap_um
                )
        if self.decoupling_samples is None:
            return pa, None
        dec: BySource[DecouplingFigures] = {}
        for name, ff in self.conditions.items():
            probe = probe_of((DEC, name))
            samples = self.decoupling_samples
            _merge(dec, run_decoupling(m, clock, probe, {name: ff}, samples_per_axis=samples,
                                       **options(DEC)))  # fmt: skip
        return pa, dec


def _merge(into: dict[str, dict[str, Any]], part: dict[str, dict[str, Any]]) -> None:
    for source, by_condition in part.items():
        into.setdefault(source, {}).update(by_condition)


def units_of(conditions: list[str], decoupling: bool) -> list[Unit]:
    """Pose accuracy, then decoupling (when run), per condition."""
    tests = [PA, DEC] if decoupling else [PA]
    return [(test, name) for test in tests for name in conditions]


def deal_units(weights: Mapping[Unit, int], workers: int) -> list[list[Unit]]:
    """The units dealt to at most ``workers`` processes, the heaviest first to the least
    loaded (each list in the units' order of ``weights``); no empty list."""
    loads = [0] * max(1, min(workers, len(weights)))
    dealt: list[list[Unit]] = [[] for _ in loads]
    for unit in sorted(weights, key=lambda u: -weights[u]):
        k = loads.index(min(loads))
        dealt[k].append(unit)
        loads[k] += weights[unit]
    order = list(weights)
    return [sorted(units, key=order.index) for units in dealt if units]


def forkable(cameras: Mapping[str, object]) -> bool:
    """Whether the probe's frames can be left out exactly: simulated cameras whose grabs take
    a fixed time (no dropped frames, no timeouts), on a system that forks."""
    return can_fork() and all(
        isinstance(c, SimCamera) and not (c.faults.drop_rate or c.faults.timeout_rate)
        for c in cameras.values()
    )


def run_demo_tests(
    tests: DemoTests,
    probe: VisionProbe,
    cameras: Mapping[str, SimCamera],
    workers: int | None = None,
) -> tuple[BySource[PoseAccuracyFigures], BySource[DecouplingFigures] | None]:
    """The demo's tests, measured by ``probe`` (over ``cameras``) and by ground truth.

    With ``workers`` > 1 (None: one per core) and :func:`forkable` cameras, the units are
    dealt to forked processes (see the module docstring); otherwise every unit runs here, in
    turn, with ``probe``.
    """
    progress = tests.options["progress"]
    workers = workers or os.cpu_count() or 1
    if workers <= 1 or not forkable(cameras):
        return tests.run(lambda _unit: probe, lambda _test: progress)
    units = tests.units()
    dealt = deal_units({u: tests.weight(u) for u in units}, workers)
    clock_only = ClockOnlyProbe(cameras, probe.frames)

    def worker(k: int, tick: Callable[..., None]) -> dict[Unit, Any]:
        mine = set(dealt[k])
        probe.search_threads = False  # every core has a process of the evaluation
        live = {u: u in mine for u in units}
        current: list[Unit] = []

        def probe_of(unit: Unit) -> PositionProbe:
            current[:] = [unit]
            return probe if live[unit] else clock_only

        def progress_of(test: str) -> Callable[[str, int, int], None] | None:
            if test == "multi-directional":
                return tick if k == 0 else None  # ground truth only: counted by one process
            return lambda stage, done, total: tick(stage, done, total) if live[current[0]] else None

        pa, dec = tests.run(probe_of, progress_of)
        out: dict[Unit, Any] = {}
        for test, name in mine:
            figures = pa if test == PA else dec
            assert figures is not None
            out[(test, name)] = figures["vision"][name]
        return out

    found: dict[Unit, Any] = {}
    for part in fork_map(worker, list(range(len(dealt))), len(dealt), progress):
        found.update(part)
    # here: the same sequence without frames, for the ground truth and the platform's state
    pa, dec = tests.run(lambda _unit: clock_only, lambda _test: None)
    for (test, name), figures in found.items():  # (the multi-directional test is by truth)
        into: Any = pa if test == PA else dec
        into["vision"][name] = figures
    return pa, dec
