"""ISO 9283 beyond pose accuracy: distance accuracy and repeatability, pose stabilisation time,
and drift of pose accuracy over a long run, per condition of an evaluation.

Each runs like :func:`~microcal.procedures.evaluation.run_pose_accuracy`: the positions are
displacements from a home pose measured first in each condition, commanded through that
condition (uncompensated, matrix, optimal, closed loop), measured by the cameras and, on the
simulator, by ground truth.

- :func:`run_distance`: the two poses ``p1`` and ``p2`` visited in turn, ``cycles`` times;
  AD and RD (clause 7.4) from the attained distances.
- :func:`run_stabilisation`: ``cycles`` moves from ``p2`` to ``p1``; after the device reports
  "stopped" the position is sampled for ``window_s``; the time until it stays within
  ``band_um`` of where it comes to rest (clause 7.5).
- :func:`run_drift`: ``p1`` visited every ``interval_s`` for ``duration_s``; AP of each visit,
  and the drift dAP between the first and the last (clause 7.7). The standard's run lasts
  8 hours; an hour shows the thermal and creep drifts of a stage in a lab.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .._validation import FloatArray
from ..control.feedforward import FeedForward
from ..devices.base import Clock, Manipulator
from ..metrics import (
    DistanceStatistics,
    distance_statistics,
    drift,
    pose_statistics,
    stabilisation_time_s,
)
from . import trials
from .evaluation_figures import BySource, DriftFigures, StabilisationFigures
from .trials import PositionProbe, aimed_poses_um

__all__ = ["run_distance", "run_drift", "run_stabilisation"]

Progress = Callable[[str, int, int], None]


def run_distance(
    manipulator: Manipulator,
    clock: Clock,
    probe: PositionProbe | None,
    conditions: dict[str, FeedForward | None],
    p1_um: FloatArray,
    p2_um: FloatArray,
    *,
    cycles: int = 3,
    settle_s: float = 5.0,
    truth: Callable[[], FloatArray] | None = None,
    progress: Progress | None = None,
) -> BySource[DistanceStatistics]:
    """Distance accuracy AD and repeatability RD (ISO 9283 clause 7.4) between two poses.

    Returns
    -------
    dict
        ``{source: {condition: DistanceStatistics}}``; ``cycles`` >= 2.
    """
    out: BySource[DistanceStatistics] = {s: {} for s in trials.sources(probe, truth)}
    for name, command in trials.commanders(manipulator, conditions).items():
        home = trials.visit(command, np.zeros(3), manipulator, clock, settle_s, probe, truth)
        got: dict[str, list[list[FloatArray]]] = {k: [[], []] for k in home}
        for c in range(cycles):
            for i, pose in enumerate((p1_um, p2_um)):
                for source, p in trials.visit(command, pose, manipulator, clock, settle_s, probe,
                                        truth).items():  # fmt: skip
                    got[source][i].append(p - home[source])
            if progress:
                progress(f"distance accuracy, {name}", c + 1, cycles)
        aim1, aim2 = aimed_poses_um(conditions[name], np.array([p1_um, p2_um]))
        for source, (a1, a2) in got.items():
            ok = np.all(np.isfinite(a1), axis=1) & np.all(np.isfinite(a2), axis=1)
            if ok.sum() >= 2:
                stats = distance_statistics(aim1, aim2, np.array(a1)[ok], np.array(a2)[ok])
                out[source][name] = stats
    return out


def run_stabilisation(
    manipulator: Manipulator,
    clock: Clock,
    probe: PositionProbe | None,
    conditions: dict[str, FeedForward | None],
    p1_um: FloatArray,
    p2_um: FloatArray,
    *,
    cycles: int = 3,
    band_um: float = 2.0,
    window_s: float = 6.0,
    truth: Callable[[], FloatArray] | None = None,
    progress: Progress | None = None,
) -> BySource[StabilisationFigures]:
    """Pose stabilisation time (ISO 9283 clause 7.5) at ``p1`` after a move from ``p2``.

    The "attained" signal is the device's "stopped"; the position is then measured as fast as
    the probe goes (each sample one vision measurement) until ``window_s`` has passed. The
    band must exceed the measurement's own noise (the cameras': about 1.5 µm for a 5-frame
    point on the thesis's platform), or the noise alone keeps the pose "unsettled".

    Returns
    -------
    dict
        ``{source: {condition: StabilisationFigures}}`` (the band, the time of each cycle,
        their mean and the worst).
    """
    out: BySource[StabilisationFigures] = {s: {} for s in trials.sources(probe, truth)}
    for name, command in trials.commanders(manipulator, conditions).items():
        times: dict[str, list[float | None]] = {k: [] for k in out}
        for c in range(cycles):
            command(p2_um)
            manipulator.wait_until_stopped(clock)
            command(p1_um)
            manipulator.wait_until_stopped(clock)
            signal = clock.now_s()
            t: list[float] = []
            samples: dict[str, list[FloatArray]] = {k: [] for k in out}
            while not t or t[-1] - signal < window_s:
                for source, p in trials.measure_by_sources(probe, truth, p1_um).items():
                    samples[source].append(p)
                t.append(clock.now_s())
                if len(t) > 1 and t[-1] <= t[-2]:
                    clock.sleep(0.01)  # a probe that takes no time: sample every 10 ms
                    t[-1] = clock.now_s()
            for source, ps in samples.items():
                p = np.array(ps)
                ok = np.all(np.isfinite(p), axis=1)
                times[source].append(
                    stabilisation_time_s(np.array(t)[ok], p[ok], band_um, signal_s=signal)
                    if ok.sum() >= 2
                    else None
                )
            if progress:
                progress(f"stabilisation, {name}", c + 1, cycles)
        for source, ts in times.items():
            settled = [x for x in ts if x is not None]
            out[source][name] = StabilisationFigures(
                band_um=band_um,
                window_s=window_s,
                times_s=ts,
                mean_s=float(np.mean(settled)) if settled else None,
                max_s=float(np.max(settled)) if len(settled) == len(ts) else None,
            )
    return out


def run_drift(
    manipulator: Manipulator,
    clock: Clock,
    probe: PositionProbe | None,
    conditions: dict[str, FeedForward | None],
    p1_um: FloatArray,
    *,
    duration_s: float = 3600.0,
    interval_s: float = 600.0,
    settle_s: float = 5.0,
    truth: Callable[[], FloatArray] | None = None,
    progress: Progress | None = None,
) -> BySource[DriftFigures]:
    """Drift of pose accuracy (ISO 9283 clause 7.7) over ``duration_s``.

    Every ``interval_s`` at most (evenly, the last visit at ``duration_s``) each condition
    measures its home and then ``p1`` (the conditions
    take turns, so they see the same hour); AP_P of each visit, and dAP = |AP(last) -
    AP(first)|.

    Returns
    -------
    dict
        ``{source: {condition: DriftFigures}}`` (the time and AP_P of each visit, and dAP).
    """
    out: BySource[DriftFigures] = {s: {} for s in trials.sources(probe, truth)}
    commanders = trials.commanders(manipulator, conditions)
    visits = int(np.ceil(duration_s / interval_s - 1e-9)) + 1  # evenly, the last at the end
    series: dict[str, dict[str, tuple[list[float], list[float]]]] = {
        s: {n: ([], []) for n in commanders} for s in out
    }
    aims = {name: aimed_poses_um(conditions[name], np.array([p1_um]))[0] for name in commanders}
    start = clock.now_s()
    for v in range(visits):
        clock.sleep(max(0.0, start + v * duration_s / (visits - 1) - clock.now_s()))
        for name, command in commanders.items():
            home = trials.visit(command, np.zeros(3), manipulator, clock, settle_s, probe, truth)
            at = trials.visit(command, p1_um, manipulator, clock, settle_s, probe, truth)
            for source, p in at.items():
                rel = (p - home[source])[None, :]
                if np.all(np.isfinite(rel)):
                    series[source][name][0].append(clock.now_s() - start)
                    series[source][name][1].append(pose_statistics(aims[name], rel).ap_p_um)
        if progress:
            progress("drift", v + 1, visits)
    for source, per in series.items():
        for name, (t, ap) in per.items():
            out[source][name] = DriftFigures(
                t_s=t, ap_p_um=ap, drift_ap_um=drift(ap[0], ap[-1]) if len(ap) >= 2 else None
            )
    return out
