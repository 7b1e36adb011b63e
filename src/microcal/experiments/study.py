"""A study: the whole procedure on many seeded platforms of a preset, against the oracle.

What a lab uses to plan (how many poses, which model, for its noise and travel) and what
microcal's accuracy claims rest on: one manipulator proves little, the population of the
``population`` preset does. For each seed, in its own process:

1. **Acquisition** of ``poses`` random commands over the thesis's travel, each approached
   from ``approach_um`` past it on a random side (so that the approach directions vary apart
   from the positions), settled for ``settle_s``, with the journal's approach directions and
   temperature. The fast path measures each pose by projecting the true end-effector
   through the platform's true cameras with the virtual point's pixel noise (thesis Table
   4-1) and triangulating (:class:`~microcal.sim.synthetic_run.ProjectedProbe`); with
   ``render`` the demo's full pipeline runs instead (rendered calibration images and
   frames, detection, measurement).
2. **Identification** on the first poses (the thesis's share) of the matrix model, the
   thesis's quadratic model (``quadratic``) and the model whose family is chosen by held-out
   error (``auto``), each with the approach directions and the temperature as extra inputs;
   validation on the rest, next to the **oracle**: the true kinematics with every part
   whose form is known to it (static polynomial, reversal and its change along the travel,
   thermal terms) re-estimated from the same measurements by least squares, the
   non-polynomial errors (straightness, Abbe, periodic) taken as they truly are. It is the
   floor: a model that knows the truth's form and is limited only by the same measurement
   noise. (The truth itself, inverted exactly, would reach AP 0 by truth.)
3. **Evaluation** (ISO 9283 pose accuracy at the Table 5-2 poses, ``cycles`` cycles, by truth
   and by the probe) without compensation, with each model's compensator and with the
   oracle's (its map inverted exactly, approached from below as the compensators are);
   the multi-directional variation vAP by truth; and the **coverage** of the predicted
   uncertainty: how often the true error of a compensated position lies in
   the 95 % region of its predicted covariance (the model's coefficient covariance
   propagated to the position, plus the lack of fit the validation residuals show beyond
   the measurement noise).
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from multiprocessing import get_context
from typing import Any

import numpy as np
import scipy.stats

from .._parallel import can_fork, ignore_interrupts
from .._validation import FloatArray
from ..control.closed_loop import ClosedLoop, ClosedLoopSummary, Measure
from ..control.conditions import closed_loop_condition
from ..control.feedforward import APPROACH_UM, FeedForward, extra_inputs_reader
from ..control.visual_servo import ServoConfig
from ..devices.base import Clock
from ..errors import DegenerateDataError, DeviceError, InputError, LimitError
from ..kinematics.adaptive_design import ADAPTIVE, AdaptiveSettings
from ..kinematics.designs import DESIGNS, make_design
from ..kinematics.extra_inputs import APPROACH_INPUTS, extra_input
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..kinematics.models import KinematicModel, fit_model
from ..kinematics.terms import JOINTS
from ..procedures.acquisition import AcquisitionConfig
from ..procedures.adaptive import AdaptiveDesign, AdaptiveResult
from ..procedures.evaluation import (
    PositionProbe,
    RunOptions,
    run_multi_directional,
    run_pose_accuracy,
)
from ..procedures.evaluation_figures import BySource, MultiDirectionalFigures, PoseAccuracyFigures
from ..procedures.identification import calibrate_manipulator, default_train
from ..sim import platform
from ..sim.kinematics import TrueKinematics, invert_map
from ..sim.manipulator import SimManipulator
from ..sim.platforms import PRESETS
from ..sim.population_prior import PriorEstimator, fit_prior_estimator, known_form_terms
from ..sim.synthetic_run import ProjectedProbe
from ..thesis.experiment import TABLE_5_2_POSES_UM, WORKSPACE_MAX_UM, WORKSPACE_MIN_UM
from .adaptive_run import (
    FRAME_S,
    TIP_TEST_POSES,
    PoseTimes,
    acquire_fast_poses,
    adaptive_curve,
    coverage_of,
    p95_um,
    poses_to_match,
    random_curve,
    run_adaptive_fast,
    static_tip_errors_um,
    tip_errors_um,
    tip_test_joints_um,
)
from .demo import demo_design_seed
from .study_figures import AdaptiveFigures, Coverage, FigureSummary, SeedRun, Study

__all__ = ["MODELS", "StudyConfig", "run_seed", "run_study", "summarize_runs"]

#: The models a study identifies and compensates with, besides the matrix model.
MODELS: tuple[str, ...] = ("quadratic", "smooth", "auto")
#: Probability content of the uncertainty region whose coverage is checked.
COVERAGE_LEVEL = 0.95


@dataclass(frozen=True)
class StudyConfig:
    """What each seed's run does (see the module docstring)."""

    poses: int = 170
    cycles: int = 3
    settle_s: float = 5.0
    approach_um: float = 300.0
    render: bool = False
    frames_per_pose: int = 5
    design: str = "random"
    closed_loop: bool = False
    """Evaluate the ``closed_loop`` condition as well: the ``auto`` model's move, then visual
    servoing with the probe (:mod:`microcal.control.visual_servo`) to ``tolerance_um``."""
    tolerance_um: float = 0.5
    overrides: Mapping[str, object] = field(default_factory=dict)
    """Simulator settings (a rig file's ``overrides``) applied to every seed's platform."""
    prior: bool = False
    """On ``population`` platforms, add the ``prior`` figures: the Bayes estimator under the
    draw's own prior (:mod:`~microcal.sim.population_prior`): what estimating the
    profiles costs any model."""
    until_um: float | None = None
    """The adaptive design's tolerance (``--until-um``): needed with ``design="adaptive"``."""
    max_poses: int = 400
    """The adaptive design's most poses."""
    adaptive_frames: int = 20
    """Frames per camera the adaptive design averages per pose (a pose costs its moves and
    settling; its frames little)."""
    random_poses: int = 300
    """With the adaptive design: the random design on the same seed is grown to this many
    poses (in steps of 10) to find how many it needs for the adaptive run's true error."""

    def __post_init__(self) -> None:
        if self.design not in (*DESIGNS, ADAPTIVE):
            raise InputError(f"design: expected one of {[*DESIGNS, ADAPTIVE]}, got {self.design!r}")
        if self.design == ADAPTIVE and self.until_um is None:
            raise InputError("--design adaptive: give the tolerance with --until-um")
        if self.design != ADAPTIVE and self.until_um is not None:
            raise InputError("--until-um: only the adaptive design stops on a tolerance")
        if self.poses < 40:
            raise InputError(f"poses: expected 40 or more, got {self.poses}")
        if self.cycles < 1:
            raise InputError(f"cycles: expected 1 or more, got {self.cycles}")
        if not (np.isfinite(self.tolerance_um) and self.tolerance_um > 0):
            raise InputError(f"tolerance_um: expected > 0, got {self.tolerance_um}")
        if not self.settle_s >= 0 or not self.approach_um >= 0:
            raise InputError("settle_s and approach_um: expected >= 0")


_PRIOR_ONLY = (
    "prior: only the population preset draws its platforms from a prior, got preset "
    "{preset!r}; leave out --prior"
)

#: The oracle's re-estimated inputs: approach directions and temperature.
ORACLE_INPUTS: tuple[str, ...] = (*JOINTS, "sx", "sy", "sz", "T")


def _oracle_inputs(temps: FloatArray) -> tuple[str, ...]:
    """The oracle's inputs for a run at these temperatures: a room held constant leaves no
    thermal term to estimate."""
    return ORACLE_INPUTS if np.ptp(temps) > 0 else ORACLE_INPUTS[:-1]


def _input_columns(
    d_um: FloatArray, signs: FloatArray, temps: FloatArray | float, inputs: Sequence[str]
) -> FloatArray:
    """(N, len(inputs)) columns of joints, approach signs and temperature (a scalar for all)
    in the order of :data:`ORACLE_INPUTS`."""
    t = np.broadcast_to(np.asarray(temps, dtype=np.float64), (d_um.shape[0],))
    out: FloatArray = np.column_stack([d_um, signs, t])[:, : len(inputs)]
    return out


def fit_oracle_correction(
    truth: TrueKinematics, d_um: FloatArray, signs: FloatArray, temps: FloatArray,
    p_um: FloatArray,
) -> KinematicModel:  # fmt: skip
    """The oracle's re-estimate: the correction to the truth, in the terms of the truth's
    known form (quadratic, reversal and its slope along the travel, linear thermal), fitted
    by least squares (every term) to the measurements' departure from the truth.

    Parameters
    ----------
    d_um, signs : (N, 3) float
    temps : (N,) float
    p_um : (N, 3) float
    """
    inputs = _oracle_inputs(temps)
    u = _input_columns(d_um, signs, temps, inputs)
    r = p_um - truth.position_um(d_um, signs, temps)
    return fit_model(u, r, known_form_terms(inputs), kind="polynomial", inputs=inputs)


def oracle_position_um(
    truth: TrueKinematics, correction: KinematicModel, d_um: FloatArray, signs: FloatArray,
    temps: FloatArray | float,
) -> FloatArray:  # fmt: skip
    """The oracle's prediction at (N, 3) joints, signs and temperatures, (N, 3) µm."""
    u = _input_columns(d_um, signs, temps, correction.inputs)
    return truth.position_um(d_um, signs, temps) + correction.predict_um(u)


#: A map of joints, approach signs (N, 3) and a temperature to positions (N, 3), µm.
PositionMap = Callable[[FloatArray, FloatArray, float], FloatArray]


class ExactFeedForward(FeedForward):
    """A compensator that inverts a given map exactly: reversal at +1 after the fixed
    approach from below, the temperature now (the oracle's, and the prior's)."""

    def __init__(self, manipulator: SimManipulator, clock: Clock, position: PositionMap) -> None:
        super().__init__(manipulator, manipulator.truth.static, "optimal", None, clock)
        self.truth = manipulator.truth
        self.position = position
        self.sim = manipulator
        self.approach_um = APPROACH_UM

    def home_um(self) -> FloatArray:
        """The map's position at zero joints now, (3,) µm."""
        t = self.sim.temperature_at(self.sim.clock.now_s())
        out: FloatArray = self.position(np.zeros((1, 3)), np.ones((1, 3)), t)[0]
        return out

    def joints_for(self, p_um: Any) -> FloatArray:
        """The joints whose mapped position is ``p_um``, (3,) µm."""
        t = self.sim.temperature_at(self.sim.clock.now_s())
        p = np.asarray(p_um, dtype=np.float64).reshape(1, 3)
        ones = np.ones((1, 3))
        d0 = np.asarray(
            np.linalg.solve(self.truth.static.R, (p - self.truth.static.p_base_um).T).T, np.float64
        )
        d = invert_map(lambda d: self.position(d, ones, t), p, d0)
        out: FloatArray = d[0]
        return out


def oracle_feed_forward(
    manipulator: SimManipulator, clock: Clock, correction: KinematicModel
) -> ExactFeedForward:
    """The oracle compensator: the oracle's map (:func:`oracle_position_um`) inverted."""
    return ExactFeedForward(manipulator, clock, functools.partial(
        oracle_position_um, manipulator.truth, correction))  # fmt: skip


def prior_feed_forward(
    manipulator: SimManipulator, clock: Clock, estimator: PriorEstimator
) -> ExactFeedForward:
    """The prior's estimator as a compensator: the kriging map of
    :mod:`~microcal.sim.population_prior` inverted exactly."""

    def position(d: FloatArray, signs: FloatArray, t: float) -> FloatArray:
        return estimator.predict_um(_input_columns(d, signs, t, estimator.inputs))

    return ExactFeedForward(manipulator, clock, position)


def _coverage(
    model: KinematicModel,
    ff: FeedForward,
    sim: SimManipulator,
    lack_um2: FloatArray,
    meas_cov_um2: FloatArray,
    poses_um: FloatArray,
) -> Coverage:
    """How often the true error of a compensated position lies in its predicted 95 % region.

    For each test pose (absolute: the model's base plus the pose), the compensator's joints,
    the predicted covariance (coefficients propagated, plus the lack of fit ``lack_um2`` per
    axis; plus ``meas_cov_um2`` for the error as measured), and the true error there.
    """
    limit = float(scipy.stats.chi2.ppf(COVERAGE_LEVEL, 3))
    inside_truth = inside_vision = 0
    sq: list[float] = []
    t = sim.temperature_at(sim.clock.now_s())
    for pose in poses_um:
        target = ff.home_um() + pose
        d = ff.joints_for(target)
        extra = None if ff.extra is None else np.asarray(ff.extra())
        u = d if extra is None else np.concatenate([d, extra])
        var = model.prediction_std_um(u[None, :])[0] ** 2 + lack_um2
        e = sim.truth.position_um(d[None, :], np.ones((1, 3)), t)[0] - target
        m2 = float(np.sum(e**2 / var))
        sq.append(m2)
        inside_truth += m2 <= limit
        c = np.diag(var) + meas_cov_um2
        inside_vision += float(e @ np.linalg.solve(c, e)) <= limit
    n = len(poses_um)
    return Coverage(truth=inside_truth / n, vision=inside_vision / n, mean_sq=float(np.mean(sq)))


def run_seed(preset: str, seed: int, config: StudyConfig | None = None) -> SeedRun:
    """One seed of a study: acquisition, identification, evaluation (the module docstring).

    Returns
    -------
    SeedRun
        Its figures (``to_json()``: one entry of study.json's ``runs``).
    """
    config = config or StudyConfig()
    t0 = time.perf_counter()
    plat = platform(preset, seed=seed, overrides=config.overrides)
    if config.prior and plat.population is None:
        raise InputError(_PRIOR_ONLY.format(preset=preset))
    kind = "random" if config.design == ADAPTIVE else config.design
    d = make_design(kind, config.poses, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM,
                    demo_design_seed(seed))  # fmt: skip
    adaptive: AdaptiveResult | None = None
    times = PoseTimes.empty()
    rig_time_s = float("nan")
    fast_probe = ProjectedProbe.on_platform(plat, np.random.default_rng([seed, 7]))
    acq = AcquisitionConfig(approach_um=config.approach_um, approach_seed=demo_design_seed(seed))
    probe: PositionProbe = fast_probe
    servo_measure: Measure = fast_probe.measure_with_covariance
    if config.render and config.design == ADAPTIVE:
        raise InputError("--render: the adaptive design runs on the fast path only")
    if config.render:
        from ..vision.probe import VisionProbe
        from .demo import run_demo

        t_acq = plat.clock.now_s()
        demo = run_demo(seed, config.poses, plat=plat, evaluate=False,
                        approach_um=config.approach_um,
                        frames_per_pose=config.frames_per_pose)  # fmt: skip
        ok = demo.measured_ok
        d = d[ok]
        p = np.array([mm.p_um for mm in demo.measurements])[ok]
        cov = np.array([mm.cov_um2 for mm in demo.measurements])[ok]
        rec = [r for r, keep in zip(demo.records, ok, strict=True) if keep]
        signs = np.array([[r.journaled(extra_input(a).column) for a in APPROACH_INPUTS]
                          for r in rec], dtype=float)  # fmt: skip
        temps = np.array([r.readings[extra_input("temperature").column] for r in rec], dtype=float)
        rendered = VisionProbe(plat.cameras, demo.calibration.models(), plat.scene.board,
                               frames=config.frames_per_pose)  # fmt: skip
        rig_time_s = plat.clock.now_s() - t_acq
        probe, servo_measure = rendered, rendered.measure_with_covariance
    elif config.design == ADAPTIVE:
        times = PoseTimes.empty()
        settings = adaptive_settings(config, seed)
        adaptive = run_adaptive_fast(plat, settings, acq, config.settle_s, fast_probe, times,
                                     config.adaptive_frames)  # fmt: skip
        seen = adaptive.measured
        ok = seen.ok
        assert seen.cov_um2 is not None
        d, p, cov = seen.d_um[ok], seen.p_um[ok], seen.cov_um2[ok]
        signs, temps = seen.signs[ok], seen.temperature_c[ok]
        rig_time_s = times.total_s + adaptive.fit_s
    else:
        t_acq = plat.clock.now_s()
        seen = acquire_fast_poses(plat, d, list(range(1, len(d) + 1)), acq, config.settle_s,
                                  fast_probe, read_sensors=False)  # fmt: skip
        assert seen.cov_um2 is not None
        p, cov, signs, temps = seen.p_um, seen.cov_um2, seen.signs, seen.temperature_c
        rig_time_s = plat.clock.now_s() - t_acq + FRAME_S * fast_probe.frames * len(d)
        ok = np.all(np.isfinite(p), axis=1)
        d, p, cov, signs, temps = d[ok], p[ok], cov[ok], signs[ok], temps[ok]
    n_fit = default_train(len(d))
    extra = {name: signs[:, k] for k, name in enumerate(APPROACH_INPUTS)}
    if np.ptp(temps) > 0:  # a room held constant (the thesis preset) gives nothing to fit
        extra["temperature"] = temps
    fits: dict[str, ManipulatorCalibration] = {}
    validation: dict[str, float] = {}
    families: dict[str, str] = {}
    for name in MODELS:
        cal, ids = calibrate_manipulator(
            "m1", d, p, "polynomial", train=n_fit, extra_inputs=extra, family=name, seed=seed
        )
        fits[name] = cal
        validation[name] = float(ids["polynomial"].validation["mean_um"])  # type: ignore[arg-type]
        validation["matrix"] = float(ids["matrix"].validation["mean_um"])  # type: ignore[arg-type]
        families[name] = str(cal.model.selection.get("family", "quadratic"))
    sim = plat.manipulator
    correction = fit_oracle_correction(sim.truth, d[:n_fit], signs[:n_fit], temps[:n_fit],
                                       p[:n_fit])  # fmt: skip
    oracle = oracle_position_um(sim.truth, correction, d[n_fit:], signs[n_fit:], temps[n_fit:])
    validation["oracle"] = float(np.linalg.norm(p[n_fit:] - oracle, axis=1).mean())
    sensors = {"temperature": lambda: sim.temperature_at(plat.clock.now_s())}
    conditions: dict[str, FeedForward | None] = {"uncalibrated": None}
    conditions["matrix"] = FeedForward(sim, fits["auto"].matrix_model or fits["auto"].model,
                                       "matrix")  # fmt: skip
    for name in MODELS:
        model = fits[name].model
        conditions[name] = FeedForward(sim, model, "optimal",
                                       extra_inputs_reader(model, sensors), plat.clock)  # fmt: skip
    conditions["oracle"] = oracle_feed_forward(sim, plat.clock, correction)
    if adaptive is not None and adaptive.final.model is not None:
        final = adaptive.final.model
        reader = extra_inputs_reader(final, sensors)
        conditions[ADAPTIVE] = FeedForward(sim, final, "optimal", reader, plat.clock)
    if config.prior and plat.population is not None:
        inputs = _oracle_inputs(temps)
        u = _input_columns(d, signs, temps, inputs)
        noise = np.diagonal(cov, axis1=1, axis2=2)
        estimator = fit_prior_estimator(plat.population, u[:n_fit], inputs, p[:n_fit],
                                        noise[:n_fit])  # fmt: skip
        validation["prior"] = float(
            np.linalg.norm(p[n_fit:] - estimator.predict_um(u[n_fit:]), axis=1).mean()
        )
        conditions["prior"] = prior_feed_forward(sim, plat.clock, estimator)
    if config.closed_loop:
        auto = fits["auto"].model
        conditions["closed_loop"] = closed_loop_condition(
            sim, fits["auto"], servo_measure, plat.clock,
            extra_inputs_reader(auto, sensors), ServoConfig(tolerance_um=config.tolerance_um),
            settle_s=config.settle_s, truth=plat.truth_position_um,
        )  # fmt: skip
    # the tip's error right after the calibration (the clock has not moved since it ended):
    # what the calibration delivers, before the evaluation's hours let the room drift
    t_cal = sim.temperature_at(plat.clock.now_s())
    tip: dict[str, float] = {}
    for name, ff in conditions.items():
        if ff is None or isinstance(ff, ClosedLoop):
            continue
        if isinstance(ff, ExactFeedForward):
            errors, _ = tip_errors_um(ff, sim)
        else:
            targets = sim.truth.position_um(tip_test_joints_um(), np.ones((TIP_TEST_POSES, 3)),
                                            t_cal)  # fmt: skip
            errors = static_tip_errors_um(ff.model, sim, targets, t_cal) if (
                ff.method == "optimal") else tip_errors_um(ff, sim)[0]  # fmt: skip
        tip[name] = p95_um(errors)
    adaptive_figures = None
    if adaptive is not None:
        adaptive_figures = _adaptive_figures(preset, seed, config, adaptive, times, sim, t_cal)
    loop_summary: ClosedLoopSummary | None = None
    options = RunOptions(settle_s=config.settle_s, truth=plat.truth_position_um, progress=None)
    pa: BySource[PoseAccuracyFigures] = {"truth": {}, "vision": {}}
    vap: BySource[MultiDirectionalFigures] = {"truth": {}}
    failed: dict[str, str] = {}
    nan = float("nan")
    chosen = families["auto"]
    for name, ff in conditions.items():  # a condition that cannot reach a pose is reported
        one = {name: ff}
        if name == "auto" and chosen in MODELS and chosen in pa["truth"]:
            # the held-out choice fell on a family fitted above: the same model, evaluated
            for source in pa:
                pa[source]["auto"] = pa[source][chosen]
            vap["truth"]["auto"] = vap["truth"][chosen]
            if chosen in failed:
                failed["auto"] = failed[chosen]
            continue
        try:
            got = run_pose_accuracy(sim, plat.clock, probe, one, cycles=config.cycles, **options)
            if isinstance(ff, ClosedLoop):
                loop_summary = ff.summary()
            # by truth, which has no noise, one cycle of the multi-directional test tells all
            got_v = run_multi_directional(sim, plat.clock, None, one, cycles=1, **options)
        except (LimitError, DegenerateDataError, DeviceError) as exc:
            failed[name] = str(exc)
            got = {s: {name: PoseAccuracyFigures(nan, nan)} for s in ("truth", "vision")}
            got_v = {"truth": {name: MultiDirectionalFigures(nan, nan)}}
        for source in pa:
            pa[source] |= got[source]
        vap["truth"] |= got_v["truth"]
    coverage = {}
    meas_cov = np.mean(cov, axis=0)
    for name in MODELS:
        model = fits[name].model
        cols = list(model.extra_inputs)
        order = ["sx", "sy", "sz", "T"]
        u_val = np.column_stack([d[n_fit:]] + [
            np.column_stack([signs, temps])[n_fit:, order.index(c)] for c in cols
        ])  # fmt: skip
        resid = p[n_fit:] - model.predict_um(u_val)
        lack = np.maximum(np.mean(resid**2, axis=0) - np.diagonal(meas_cov), 0.0)
        ff = conditions[name]
        assert ff is not None
        try:
            coverage[name] = _coverage(model, ff, sim, lack, meas_cov, TABLE_5_2_POSES_UM)
        except (LimitError, DegenerateDataError):
            coverage[name] = Coverage(nan, nan, nan)
    truth, vision = pa["truth"], pa["vision"]
    return SeedRun(
        seed=seed,
        uncalibrated_ap_truth_mean_um=truth["uncalibrated"].mean_ap_p_um,
        validation_mean_um=validation,
        ap_truth_mean_um={k: v.mean_ap_p_um for k, v in truth.items()},
        ap_truth_max_um={k: v.max_ap_p_um for k, v in truth.items()},
        ap_vision_mean_um={k: v.mean_ap_p_um for k, v in vision.items()},
        vap_truth_mean_um={k: v.vap_um for k, v in vap["truth"].items()},
        coverage_95=coverage,
        family=families["auto"],
        closed_loop=loop_summary if config.closed_loop else None,
        failed=failed,
        n_poses=len(d),
        render=config.render,
        wall_s=time.perf_counter() - t0,
        rig_time_s=rig_time_s,
        tip_error_p95_um=tip,
        design=config.design,
        adaptive=adaptive_figures,
    )


def adaptive_settings(config: StudyConfig, seed: int) -> AdaptiveSettings:
    """The adaptive design of a study's seed."""
    assert config.until_um is not None
    return AdaptiveSettings(until_um=config.until_um, max_poses=config.max_poses,
                            seed=demo_design_seed(seed))  # fmt: skip


def _adaptive_figures(
    preset: str, seed: int, config: StudyConfig, result: AdaptiveResult, times: PoseTimes,
    sim: SimManipulator, temperature_c: float,
) -> AdaptiveFigures:  # fmt: skip
    """The adaptive run's curve, its predicted error's coverage at the test poses, and the
    random design grown on the same seed (the study's frames per pose) for comparison."""
    final = result.final
    curve = adaptive_curve(result, times, sim)
    coverage = coverage_model = float("nan")
    if final.model is not None:
        model = final.model
        targets = sim.truth.position_um(tip_test_joints_um(), np.ones((TIP_TEST_POSES, 3)),
                                        temperature_c)  # fmt: skip
        errors = static_tip_errors_um(model, sim, targets, temperature_c)
        from ..kinematics.compensators import Compensator

        read = extra_inputs_reader(model, {"temperature": lambda: temperature_c})
        d = Compensator(model, sim.limits_um).solve(targets, extra=None if read is None else
                                                    read()).d_um  # fmt: skip
        design = AdaptiveDesign(adaptive_settings(config, seed), WORKSPACE_MIN_UM,
                                WORKSPACE_MAX_UM, sim.limits_um, AcquisitionConfig(
                                    approach_um=config.approach_um))  # fmt: skip
        extra = design.scatter_var_um2(result.measured)
        inside = coverage_of(model, errors, np.asarray(d), temperature_c, extra,
                             inflation=final.inflation)  # fmt: skip
        coverage = float(inside.mean())
        coverage_model = float(coverage_of(model, errors, np.asarray(d), temperature_c,
                                           extra).mean())  # fmt: skip
    plat = platform(preset, seed=seed, overrides=config.overrides)
    acq = AcquisitionConfig(approach_um=config.approach_um, approach_seed=demo_design_seed(seed))
    counts = list(range(20, config.random_poses + 1, 10))
    random = random_curve(plat, seed, counts, acq, config.settle_s, config.frames_per_pose,
                          adaptive_settings(config, seed))  # fmt: skip
    reached = curve[-1].tip_error_p95_um if curve else float("nan")
    return AdaptiveFigures(
        until_um=float(config.until_um or 0.0), predicted_um=final.predicted_um,
        inflation=final.inflation, stop=final.reason, coverage_95=coverage,
        coverage_95_model=coverage_model, curve=curve,
        random_curve=random, random_poses_to_match=poses_to_match(random, reached),
    )  # fmt: skip


def _flatten(run: SeedRun) -> dict[str, float]:
    """Every number of a run's object by its dotted name, down to two levels (``seed``,
    booleans at the top and text left out)."""
    out: dict[str, float] = {}
    for key, value in run.to_json().items():
        if isinstance(value, Mapping):
            for sub, v in value.items():
                if isinstance(v, Mapping):
                    for k2, v2 in v.items():
                        if isinstance(v2, int | float):
                            out[f"{key}.{sub}.{k2}"] = float(v2)
                elif isinstance(v, int | float):
                    out[f"{key}.{sub}"] = float(v)
        elif isinstance(value, int | float) and not isinstance(value, bool) and key != "seed":
            out[key] = float(value)
    return out


def _summary(v: FloatArray) -> FigureSummary:
    ok = v[np.isfinite(v)]  # a condition that failed on a seed is counted, not averaged
    if not ok.size:
        nan = float("nan")
        return FigureSummary(nan, nan, nan, nan, failed=int(v.size))
    return FigureSummary(median=float(np.median(ok)), p90=float(np.percentile(ok, 90)),
                         min=float(ok.min()), max=float(ok.max()),
                         failed=int(v.size - ok.size))  # fmt: skip


def summarize_runs(runs: Sequence[SeedRun]) -> dict[str, FigureSummary]:
    """Median and 90th percentile of every figure over the runs (``summary`` of study.json),
    and the ratios to the oracle that the accuracy claims are made in."""
    flat = [_flatten(r) for r in runs]
    for f, r in zip(flat, runs, strict=True):
        validation, ap = r.validation_mean_um, r.ap_truth_mean_um
        for name in ("matrix", *MODELS):
            f[f"validation_over_oracle.{name}"] = validation[name] / validation["oracle"]
        for name in ap:
            if name not in ("uncalibrated", "oracle"):
                f[f"ap_truth_over_oracle.{name}"] = ap[name] / ap["oracle"]
    keys = sorted({k for f in flat for k in f})
    out = {k: _summary(np.array([f[k] for f in flat if k in f])) for k in keys}
    ratio = np.array([r.n_poses / r.adaptive.random_poses_to_match
                      if r.adaptive is not None and r.adaptive.random_poses_to_match else np.nan
                      for r in runs if r.adaptive is not None])  # fmt: skip
    if ratio.size:
        out["adaptive.poses_over_random"] = _summary(ratio)
        within = np.array([r.tip_error_p95_um.get(ADAPTIVE, np.nan) <= (r.adaptive.until_um
                           if r.adaptive else np.nan) for r in runs], dtype=float)  # fmt: skip
        out["adaptive.tip_error_within_tolerance"] = _summary(np.array([within.mean()]))
        for key in ("coverage_95", "coverage_95_model"):
            cov = np.array([getattr(r.adaptive, key) for r in runs if r.adaptive], dtype=float)
            pooled = float(np.nanmean(cov))
            out[f"adaptive.{key}.pooled"] = FigureSummary(pooled, pooled, pooled, pooled, 0)
    for name in MODELS:  # every seed has as many test poses: the pooled rate is the mean
        cov = np.array([r.coverage_95[name].truth for r in runs], dtype=float)
        ok = cov[np.isfinite(cov)]
        pooled = float(ok.mean()) if ok.size else float("nan")
        out[f"coverage_95.{name}.truth.pooled"] = FigureSummary(
            pooled, pooled, pooled, pooled, failed=int(cov.size - ok.size)
        )
    return out


def run_study(
    preset: str,
    seeds: Sequence[int],
    config: StudyConfig | None = None,
    workers: int | None = None,
    progress: Callable[[int, int, SeedRun], None] | None = None,
) -> Study:
    """Run :func:`run_seed` for every seed, each in its own process.

    Parameters
    ----------
    workers : int, optional
        Processes at once (default: the machine's cores, at most one per seed); 1 runs in
        this process.
    progress : callable (done, total, run), optional

    Returns
    -------
    Study
        Preset, seeds, runs (in seed order), summary (``to_json()``: study.json's content
        without ``format``).
    """
    if preset not in PRESETS:
        raise InputError(f"preset: expected one of {list(PRESETS)}, got {preset!r}")
    seeds = list(seeds)
    if not seeds:
        raise InputError("seeds: expected at least one seed")
    config = config or StudyConfig()
    if config.prior and preset != "population":
        raise InputError(_PRIOR_ONLY.format(preset=preset))
    workers = min(workers or os.cpu_count() or 1, len(seeds))
    runs: dict[int, SeedRun] = {}
    if workers == 1:
        for seed in seeds:
            runs[seed] = run_seed(preset, seed, config)
            if progress:
                progress(len(runs), len(seeds), runs[seed])
    else:
        saved = {k: os.environ.get(k) for k in _THREAD_VARS}
        os.environ.update(dict.fromkeys(_THREAD_VARS, "1"))  # one core per seed
        try:
            # fork where there is one (a script without a main guard works), else spawn
            method = "fork" if can_fork() else "spawn"
            # the workers leave an interrupt to this process, whose leaving the block ends
            # them (Pool.terminate): an interrupted study stops now, not after every seed
            with get_context(method).Pool(workers, initializer=ignore_interrupts) as pool:
                one = functools.partial(run_seed, preset, config=config)
                for run in pool.imap_unordered(one, seeds):
                    runs[run.seed] = run
                    if progress:
                        progress(len(runs), len(seeds), run)
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    ordered = [runs[s] for s in seeds]
    return Study(preset, seeds, ordered, summarize_runs(ordered))


_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
