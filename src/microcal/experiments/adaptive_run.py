"""The adaptive design on the simulator's fast path, and the figures it is judged by.

- :func:`acquire_fast_poses`: move to each pose (approached from its side), settle, measure
  through the projected probe; the rig time of each pose: moves and settling from the
  simulated clock, and the frames the pose would grab counted at :data:`FRAME_S` each (the
  fast path grabs none).
- :func:`run_adaptive_fast`: the adaptive loop (:mod:`~microcal.procedures.adaptive`) with
  that acquisition; the fits' wall time joins the rig time (the rig waits for them).
- :func:`tip_errors_um`: the true error of the compensated tip at test poses spread across
  the workspace (:func:`tip_test_joints_um`, a fixed scrambled Sobol set, apart from any
  design's): each test target is where the truth puts the tip at those joints, approached
  from below, at the temperature now; the compensator's joints for it, and the truth's
  position there, settled. Its 95th percentile is study.json's ``tip_error_p95_um``.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.stats
import scipy.stats.qmc as qmc

from .._validation import FloatArray
from ..control.feedforward import FeedForward
from ..errors import DegenerateDataError, DeviceError, LimitError
from ..kinematics.adaptive_design import AdaptiveSettings, joint_inputs
from ..kinematics.models import KinematicModel
from ..procedures.acquisition import AcquisitionConfig, approach_start_um
from ..procedures.adaptive import AdaptiveDesign, AdaptiveResult, Measured, run_adaptive
from ..sim import SimPlatform
from ..sim.manipulator import SimManipulator
from ..sim.synthetic_run import ProjectedProbe
from ..thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM

__all__ = [
    "FRAME_S",
    "TIP_TEST_POSES",
    "PoseTimes",
    "acquire_fast_poses",
    "run_adaptive_fast",
    "tip_errors_um",
    "tip_test_joints_um",
]

#: Time to grab one frame of every camera on the fast path, s (the thesis cameras' 15-25
#: frames per second): the frames a pose stores cost this each.
FRAME_S = 0.05
#: Test poses of the compensated tip's error.
TIP_TEST_POSES = 200
#: Seed of the test poses (a set of its own, apart from every design).
TIP_TEST_SEED = 9283
#: Attempts after a device fault, per move.
RETRIES = 3


def tip_test_joints_um(n: int = TIP_TEST_POSES) -> FloatArray:
    """Test joints spread over the workspace (scrambled Sobol, fixed seed), (n, 3) µm."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        unit = qmc.Sobol(3, scramble=True, seed=TIP_TEST_SEED).random(n)
    out: FloatArray = WORKSPACE_MIN_UM + unit * (WORKSPACE_MAX_UM - WORKSPACE_MIN_UM)
    return out


@dataclass
class PoseTimes:
    """Rig time of each pose, by part, s (lists in pose order)."""

    move_s: list[float]
    settle_s: list[float]
    frames_s: list[float]

    @classmethod
    def empty(cls) -> PoseTimes:
        return cls([], [], [])

    def extend(self, other: PoseTimes) -> None:
        self.move_s += other.move_s
        self.settle_s += other.settle_s
        self.frames_s += other.frames_s

    @property
    def per_pose_s(self) -> FloatArray:
        out: FloatArray = (np.array(self.move_s) + np.array(self.settle_s)
                           + np.array(self.frames_s))  # fmt: skip
        return out

    @property
    def total_s(self) -> float:
        return float(self.per_pose_s.sum())


def _move_retrying(m: SimManipulator, target: FloatArray, plat: SimPlatform) -> bool:
    for _ in range(RETRIES + 1):
        try:
            m.move_to_um(target)
            m.wait_until_stopped(plat.clock)
            return True
        except DeviceError:
            continue
    return False


def acquire_fast_poses(
    plat: SimPlatform,
    d_um: FloatArray,
    poses: list[int],
    config: AcquisitionConfig,
    settle_s: float,
    probe: ProjectedProbe,
    times: PoseTimes | None = None,
    frames: int | None = None,
    directions: FloatArray | None = None,
    read_sensors: bool = True,
) -> Measured:
    """Move to each pose, settle, grab and measure; a pose never reached is NaN.

    Each pose is approached from the side its number draws (or opposite its chosen
    direction); a move the device refuses or a query it does not answer is tried again up to
    :data:`RETRIES` times, as acquisition does.

    Parameters
    ----------
    d_um : (b, 3) float
        The commands of ``poses`` (1-based numbers: they draw the approach sides).
    times : PoseTimes, optional
        Each pose's rig time is appended to it.
    frames : int, optional
        Frames per camera averaged per pose (default: the probe's).
    directions : (b, 3) float, optional
        The approach directions chosen for each pose (NaN or none: drawn from the pose).
    read_sensors : bool
        Read the device's own position after each pose (``reported_um``; the query draws the
        sensor's noise from the device's random stream). Without it ``reported_um`` is NaN.
    """
    k = probe.frames if frames is None else frames
    chosen = np.full((len(d_um), 3), np.nan) if directions is None else directions
    m, clock = plat.manipulator, plat.clock
    n = d_um.shape[0]
    p, signs = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    temps, reported = np.full(n, np.nan), np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    last = m.joints_um(clock.now_s())
    current = np.ones(3)
    for i, (d, pose) in enumerate(zip(d_um, poses, strict=True)):
        t0 = clock.now_s()
        start = (approach_start_um(d, pose, config, m.limits_um, chosen[i])
                 if config.approach_um else d)  # fmt: skip
        reached = True
        for target in (start, d):
            if not _move_retrying(m, target, plat):
                reached = False
                break
            step = target - last
            current = np.where(step > 1e-3, 1.0, np.where(step < -1e-3, -1.0, current))
            last = target
        t1 = clock.now_s()
        if reached:
            clock.sleep(settle_s)
        t2 = clock.now_s()
        if reached:
            p[i], cov[i] = probe.measure_with_covariance(d, k)
            signs[i] = current
            temps[i] = m.temperature_at(clock.now_s())
            if read_sensors:
                reported[i] = m.position_um()
        else:
            last = m.joints_um(clock.now_s())
        if times is not None:  # the fast path grabs no frame: their time is counted
            times.move_s.append(t1 - t0)
            times.settle_s.append(t2 - t1)
            times.frames_s.append(FRAME_S * k if reached else 0.0)
    return Measured(np.array(d_um, dtype=np.float64), p, signs, temps, reported, cov)


def run_adaptive_fast(
    plat: SimPlatform,
    settings: AdaptiveSettings,
    config: AcquisitionConfig,
    settle_s: float,
    probe: ProjectedProbe,
    times: PoseTimes | None = None,
    frames: int | None = None,
) -> AdaptiveResult:
    """The adaptive loop on the fast path over the thesis's workspace (the module
    docstring); ``times`` gets each pose's rig time, ``frames`` per camera are averaged
    per pose (default: the probe's)."""
    design = AdaptiveDesign(settings, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM,
                            plat.manipulator.limits_um, config)  # fmt: skip

    def acquire(d: FloatArray, poses: list[int], directions: FloatArray) -> Measured:
        return acquire_fast_poses(plat, d, poses, config, settle_s, probe, times, frames,
                                  directions)  # fmt: skip

    return run_adaptive(design, acquire)


def compensated_joints_um(ff: FeedForward, targets_um: FloatArray) -> tuple[FloatArray, np.ndarray]:
    """The compensator's joints for each target (N, 3), and which it could solve (N,)."""
    d = np.full_like(targets_um, np.nan)
    ok = np.zeros(len(targets_um), dtype=bool)
    for i, target in enumerate(targets_um):
        try:
            d[i] = ff.joints_for(target)
            ok[i] = True
        except (LimitError, DegenerateDataError):
            continue
    return d, ok


def tip_errors_um(
    ff: FeedForward,
    sim: SimManipulator,
    test_um: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The true error of the compensated tip at the test joints (module docstring).

    Returns
    -------
    errors_um : (M, 3) float
        True position minus target (NaN where the compensator had no solution).
    d_um : (M, 3) float
        The compensator's joints.
    """
    d_test = tip_test_joints_um() if test_um is None else test_um
    t = sim.temperature_at(sim.clock.now_s())
    up = np.ones_like(d_test)
    targets = sim.truth.position_um(d_test, up, t)
    d, ok = compensated_joints_um(ff, targets)
    e = np.full_like(targets, np.nan)
    e[ok] = sim.truth.position_um(d[ok], up[ok], t) - targets[ok]
    return e, d


def p95_um(errors_um: FloatArray) -> float:
    """95th percentile of the errors' lengths (NaN rows count as failed: NaN if any)."""
    lengths = np.linalg.norm(errors_um, axis=1)
    if not np.all(np.isfinite(lengths)):
        return float("nan")
    return float(np.percentile(lengths, 95))


def coverage_of(
    model: KinematicModel,
    errors_um: FloatArray,
    d_um: FloatArray,
    temperature_c: float,
    extra_var_um2: FloatArray,
    level: float = 0.95,
    inflation: float = 1.0,
) -> FloatArray:
    """(M,) bool: whether each true error lies in the model's predicted ``level`` region
    (its prediction covariance at the compensated joints, approached from below, plus
    ``extra_var_um2`` per axis, times ``inflation`` squared: as the stopping rule takes it)."""
    ok = np.all(np.isfinite(errors_um), axis=1)
    u = joint_inputs(d_um[ok], np.ones_like(d_um[ok]), temperature_c, model.inputs)
    var = (model.prediction_std_um(u) ** 2 + extra_var_um2) * inflation**2
    m2 = np.sum(errors_um[ok] ** 2 / var, axis=1)
    out = np.zeros(len(errors_um), dtype=bool)
    out[ok] = m2 <= scipy.stats.chi2.ppf(level, 3)
    return out


def fit_wall(fn: Callable[[], KinematicModel]) -> tuple[KinematicModel, float]:
    """A fit and its wall time, s."""
    t0 = time.perf_counter()
    model = fn()
    return model, time.perf_counter() - t0


def static_tip_errors_um(
    model: KinematicModel, sim: SimManipulator, targets_um: FloatArray, temperature_c: float
) -> FloatArray:
    """The true error of the tip sent to each target (N, 3) by the model's compensator,
    approached from below, settled, at ``temperature_c``; (N, 3) µm, NaN where the model
    has no solution within the limits. Nothing moves: the truth is evaluated."""
    from ..control.feedforward import extra_inputs_reader
    from ..kinematics.compensators import Compensator

    read = extra_inputs_reader(model, {"temperature": lambda: temperature_c})
    extra = None if read is None else read()
    got = Compensator(model, sim.limits_um).solve(targets_um, extra=extra)
    d = np.asarray(got.d_um, dtype=np.float64)
    inside = np.all((d >= sim.limits_um[:, 0]) & (d <= sim.limits_um[:, 1]), axis=1)
    ok = np.asarray(got.converged, dtype=bool) & inside
    e = np.full_like(targets_um, np.nan)
    up = np.ones((int(ok.sum()), 3))
    e[ok] = sim.truth.position_um(d[ok], up, temperature_c) - targets_um[ok]
    return e


@dataclass(frozen=True)
class CurvePoint:
    """One point of a design's curve: after ``n_poses`` poses and ``rig_time_s``, the true
    error of the tip the model then compensates (static: the truth evaluated)."""

    n_poses: int
    rig_time_s: float
    ap_truth_mean_um: float
    tip_error_p95_um: float

    def to_json(self) -> dict[str, float | int]:
        return {"n_poses": self.n_poses, "rig_time_s": self.rig_time_s,
                "ap_truth_mean_um": self.ap_truth_mean_um,
                "tip_error_p95_um": self.tip_error_p95_um}  # fmt: skip


def curve_point(
    model: KinematicModel, sim: SimManipulator, temperature_c: float, n: int, rig_time_s: float
) -> CurvePoint:
    """The static figures of a model: the mean error at the Table 5-2 poses (from the
    model's home, as the ISO test aims them: the "true AP" of a model whose tip does not
    scatter) and the 95th percentile over the workspace's test poses."""
    from ..thesis.experiment import TABLE_5_2_POSES_UM

    read_home = model.predict_um(joint_inputs(np.zeros((1, 3)), np.ones((1, 3)), temperature_c,
                                              model.inputs))[0]  # fmt: skip
    ap = static_tip_errors_um(model, sim, read_home + TABLE_5_2_POSES_UM, temperature_c)
    d_test = tip_test_joints_um()
    targets = sim.truth.position_um(d_test, np.ones_like(d_test), temperature_c)
    tip = static_tip_errors_um(model, sim, targets, temperature_c)
    return CurvePoint(n, rig_time_s, float(np.mean(np.linalg.norm(ap, axis=1))), p95_um(tip))


def adaptive_curve(
    result: AdaptiveResult, times: PoseTimes, sim: SimManipulator
) -> list[CurvePoint]:
    """The adaptive run's curve: each step's model after the poses it was fitted on and the
    rig time until then (every pose before it, every fit up to it), at the temperature of its
    last pose (when that model would have been used)."""
    temps = result.measured.temperature_c
    cumulative = np.cumsum(times.per_pose_s)
    fits = 0.0
    out = []
    for step in result.steps:
        fits += step.fit_s
        if step.model is not None and step.poses:
            rig = float(cumulative[step.poses - 1]) + fits
            t = _last_finite(temps[: step.poses])
            out.append(curve_point(step.model, sim, t, step.poses, rig))
    return out


def random_curve(
    plat: SimPlatform,
    seed: int,
    counts: list[int],
    config: AcquisitionConfig,
    settle_s: float,
    frames: int,
    settings: AdaptiveSettings,
) -> list[CurvePoint]:
    """The random design grown on a platform of the same seed: its first ``counts`` poses
    each fitted with the adaptive design's model (the same family, inputs and workspace),
    and the rig time of those poses."""
    from ..kinematics.designs import make_design
    from .demo import demo_design_seed

    probe = ProjectedProbe.on_platform(plat, np.random.default_rng([seed, 7]))
    n = max(counts)
    d = make_design("random", n, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM, demo_design_seed(seed))
    times = PoseTimes.empty()
    measured = acquire_fast_poses(plat, d, list(range(1, n + 1)), config, settle_s, probe,
                                  times, frames)  # fmt: skip
    design = AdaptiveDesign(settings, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM,
                            plat.manipulator.limits_um, config)  # fmt: skip
    sim = plat.manipulator
    cumulative = np.cumsum(times.per_pose_s)
    out = []
    for k in counts:
        head = measured.head(k)
        model = design.fit(head)
        if model is not None:
            t = _last_finite(head.temperature_c)
            out.append(curve_point(model, sim, t, k, float(cumulative[k - 1])))
    return out


def _last_finite(values: FloatArray) -> float:
    """The last finite value (the temperature at the last pose measured)."""
    ok = values[np.isfinite(values)]
    return float(ok[-1]) if ok.size else float("nan")


def poses_to_match(curve: list[CurvePoint], error_um: float) -> int | None:
    """The fewest poses of a curve whose tip error is at most ``error_um`` (None: never)."""
    for point in curve:
        if point.tip_error_p95_um <= error_um:
            return point.n_poses
    return None
