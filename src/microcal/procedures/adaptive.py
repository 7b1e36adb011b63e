"""The adaptive calibration loop: acquire, measure, fit, choose the next poses, until the
predicted error of the compensated tip is below the tolerance everywhere.

:class:`AdaptiveDesign` holds what the design needs besides the measurements (its settings,
the workspace, the soft limits, the approach of each pose); :meth:`AdaptiveDesign.step` turns
the poses measured so far into the next batch of commands or the decision to stop
(:mod:`~microcal.kinematics.adaptive_design` says how). :func:`run_adaptive` interleaves it
with an acquisition that moves, settles and measures: whatever stores the poses (a run
directory, memory) makes it resumable, since the next step depends on the measured poses
alone.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError
from ..kinematics.adaptive_design import (
    AdaptiveSettings,
    candidate_joints_um,
    choose_batch,
    fit_adaptive_model,
    joint_inputs,
    prior_model,
    residual_variance_um2,
    start_design_um,
    tip_error_draws_um,
    workspace_grid_um,
)
from ..kinematics.models import KinematicModel
from ..kinematics.terms import JOINTS
from .acquisition import AcquisitionConfig, approach_start_um

__all__ = ["AdaptiveDesign", "AdaptiveResult", "AdaptiveStep", "Measured", "run_adaptive"]

#: The temperature joins the model's inputs only where the poses spanned this much, °C: a
#: thermal coefficient from a smaller span (a run of minutes) extrapolates wildly to the
#: temperature of an hour later.
MIN_TEMPERATURE_SPAN_C = 0.1
#: Batches the predicted error is checked on (each by the fit made before it was measured):
#: at least this many, and as many as make :data:`CHECK_POSES` poses.
CHECK_BATCHES = 2
#: Poses the predicted error is checked on, at least (small batches: more of them).
CHECK_POSES = 20
#: A fit whose effective degrees of freedom exceed this share of its poses on some axis
#: (it follows the noise) is not trusted to stop on.
MAX_EDF_SHARE = 0.67


@dataclass(frozen=True)
class Measured:
    """The poses of a run so far, in pose order (a pose not measured has NaN positions).

    Attributes
    ----------
    d_um : (N, 3) float
        Commands.
    p_um : (N, 3) float
        Measured positions in {G}.
    signs : (N, 3) float
        Each joint's approach direction (+1 / -1).
    temperature_c : (N,) float
    reported_um : (N, 3) float, optional
        The device's reported joints after the pose settled: their departure from the
        commands bounds the motion's scatter (the readout's noise included).
    cov_um2 : (N, 3, 3) float, optional
        The measured positions' covariances.
    """

    d_um: FloatArray
    p_um: FloatArray
    signs: FloatArray
    temperature_c: FloatArray
    reported_um: FloatArray | None = None
    cov_um2: FloatArray | None = None

    @classmethod
    def empty(cls) -> Measured:
        """No pose yet."""
        z = np.zeros((0, 3))
        return cls(z, z.copy(), z.copy(), np.zeros(0), z.copy(), np.zeros((0, 3, 3)))

    def __add__(self, other: Measured) -> Measured:
        rep = cov = None
        if self.reported_um is not None and other.reported_um is not None:
            rep = np.vstack([self.reported_um, other.reported_um])
        if self.cov_um2 is not None and other.cov_um2 is not None:
            cov = np.concatenate([self.cov_um2, other.cov_um2])
        return Measured(np.vstack([self.d_um, other.d_um]), np.vstack([self.p_um, other.p_um]),
                        np.vstack([self.signs, other.signs]),
                        np.concatenate([self.temperature_c, other.temperature_c]), rep,
                        cov)  # fmt: skip

    def head(self, n: int) -> Measured:
        """The first ``n`` poses."""
        return Measured(self.d_um[:n], self.p_um[:n], self.signs[:n], self.temperature_c[:n],
                        None if self.reported_um is None else self.reported_um[:n],
                        None if self.cov_um2 is None else self.cov_um2[:n])  # fmt: skip

    def __len__(self) -> int:
        return int(self.d_um.shape[0])

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: poses with a position."""
        out: np.ndarray = np.all(np.isfinite(self.p_um), axis=1) & np.all(
            np.isfinite(self.signs), axis=1
        ) & np.isfinite(self.temperature_c)  # fmt: skip
        return out


@dataclass(frozen=True)
class AdaptiveStep:
    """What one look at the measurements decided.

    Attributes
    ----------
    poses : int
        Poses commanded so far.
    used : int
        Of them, measured and fitted.
    predicted_um : float
        The predicted ``level`` error of the compensated tip over the workspace (the
        stopping rule's figure; NaN without a fit).
    max_predicted_um : float
        The largest of the test joints' own predicted ``level`` errors (NaN without a fit).
    inflation : float
        The factor (>= 1) on the model's predicted error from its check on new poses
        (:meth:`AdaptiveDesign.calibration`); both figures above include it.
    stop : bool
    reason : str
        Why it stopped or goes on, one line.
    next_um : (b, 3) float
        The next poses' commands (none when it stops).
    next_directions : (b, 3) float
        The approach directions the design chose for them (+1 / -1 per joint; NaN: the
        acquisition draws them).
    model : KinematicModel or None
    fit_s : float
        Wall time of the fit and the choice, s (the rig waits for it).
    """

    poses: int
    used: int
    predicted_um: float
    max_predicted_um: float
    inflation: float
    stop: bool
    reason: str
    next_um: FloatArray
    model: KinematicModel | None
    fit_s: float
    next_directions: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))


class AdaptiveDesign:
    """An adaptive design over a workspace (see the module docstring).

    Parameters
    ----------
    settings : AdaptiveSettings
    low_um, high_um : (3,) float
        The workspace (joint commands) to cover; a joint with low == high is held.
    limits_um : (3, 2) float
        The device's soft limits (where an approach may go).
    approach : AcquisitionConfig
        Its ``approach_um`` and ``approach_seed`` give each pose's approach directions;
        ``approach_um`` must be above 0 so that they vary.
    """

    def __init__(
        self,
        settings: AdaptiveSettings,
        low_um: FloatArray,
        high_um: FloatArray,
        limits_um: FloatArray,
        approach: AcquisitionConfig,
    ) -> None:
        if approach.approach_um <= 0:
            raise DegenerateDataError(
                "adaptive design: expected an approach distance > 0 µm (the approach "
                "directions must vary), got 0"
            )
        self.settings = settings
        self.low_um = np.asarray(low_um, dtype=np.float64)
        self.high_um = np.asarray(high_um, dtype=np.float64)
        self.limits_um = np.asarray(limits_um, dtype=np.float64)
        self.approach = approach
        self.candidates_um = candidate_joints_um(settings, self.low_um, self.high_um)
        self.test_um = workspace_grid_um(settings, self.low_um, self.high_um)
        held = self.low_um == self.high_um
        self.held_um = {j: float(self.low_um[k]) for k, j in enumerate(JOINTS) if held[k]}

    def start_um(self) -> FloatArray:
        """The first poses' commands: the space-filling start, or the one chosen under the
        smooth model's prior (``settings.start``)."""
        s = self.settings
        if s.start != "prior":
            return start_design_um(s, self.low_um, self.high_um)
        c_um = self.candidates_um
        signs = tuple(f"s{a}" for k, a in enumerate("xyz") if JOINTS[k] not in self.held_um)
        inputs = (*JOINTS, *signs)

        def inputs_for(i: int) -> FloatArray:
            return joint_inputs(c_um, self.signs_for(c_um, 1 + i), 0.0, inputs)

        prior = prior_model(inputs, self.low_um, self.high_um, inputs_for(0), self.held_um)
        test = joint_inputs(self.test_um, np.ones_like(self.test_um), 0.0, inputs)
        picks = choose_batch(prior, np.ones(3), test, inputs_for, s.start_poses, self.low_um,
                             np.ones(len(c_um), dtype=bool), s.near_share, s.exchange)  # fmt: skip
        out: FloatArray = c_um[picks]
        return out

    def signs_for(
        self, d_um: FloatArray, pose: int, direction: FloatArray | None = None
    ) -> FloatArray:
        """Approach directions joints (C, 3) arrive with as pose ``pose`` (1-based), drawn
        or, where the limits allow, the ``direction`` (3,) chosen."""
        start = approach_start_um(d_um, pose, self.approach, self.limits_um, direction)
        out: FloatArray = np.where(d_um > start, 1.0, np.where(d_um < start, -1.0, 1.0))
        return out

    def inputs(self, measured: Measured) -> tuple[str, ...]:
        """The model's inputs: joints, approach directions and, where the temperature
        spanned :data:`MIN_TEMPERATURE_SPAN_C` or more, the temperature."""
        ok = measured.ok
        temps = measured.temperature_c[ok]
        varied = temps.size > 1 and float(np.ptp(temps)) >= MIN_TEMPERATURE_SPAN_C
        signs = tuple(f"s{a}" for k, a in enumerate("xyz") if JOINTS[k] not in self.held_um)
        return (*JOINTS, *signs, *(("T",) if varied else ()))

    def scatter_var_um2(self, measured: Measured) -> FloatArray:
        """The motion's scatter per axis, bounded by the reported joints' departure from
        the commands (their mean square), (3,) µm²."""
        if measured.reported_um is None:
            return np.zeros(3)
        diff = (measured.reported_um - measured.d_um)[measured.ok]
        diff = diff[np.all(np.isfinite(diff), axis=1)]
        out: FloatArray = np.mean(diff**2, axis=0) if len(diff) else np.zeros(3)
        return out

    def test_inputs(self, measured: Measured, inputs: tuple[str, ...]) -> FloatArray:
        """The test joints' inputs: approached from below (the compensator's fixed
        approach), at the last temperature measured, (M, k)."""
        t_now = float(measured.temperature_c[measured.ok][-1])
        return joint_inputs(self.test_um, np.ones_like(self.test_um), t_now, inputs)

    def predicted_um(
        self, model: KinematicModel, measured: Measured, inputs: tuple[str, ...]
    ) -> tuple[float, float]:
        """The predicted ``level`` error of the compensated tip over the workspace, and the
        largest of the test joints' own, µm."""
        u = self.test_inputs(measured, inputs)
        radii = tip_error_draws_um(model, u, self.scatter_var_um2(measured))
        level = self.settings.level
        return float(np.quantile(radii, level)), float(np.quantile(radii, level, axis=1).max())

    def batch_starts(self, n: int) -> list[int]:
        """Poses measured before each look at the measurements, up to ``n``: the start, then
        one batch after the other."""
        s = self.settings
        return list(range(s.start_poses, n + 1, s.batch)) if n >= s.start_poses else []

    def calibration(self, measured: Measured, inputs: tuple[str, ...]) -> float:
        """How much larger the errors on new poses were than predicted: the mean squared
        standardised error of each of the last :data:`CHECK_BATCHES` batches as predicted
        by the model fitted before it was measured (its prediction variance plus the
        residual variance, per axis), over 1 (1 when there is no batch to check yet).
        The stopping rule's predicted error is multiplied by its square root where it is
        above 1: the model's stated uncertainty, checked on poses it had not seen."""
        ok = measured.ok
        starts = self.batch_starts(len(measured))
        m2: list[FloatArray] = []
        checked = max(CHECK_BATCHES, -(-CHECK_POSES // self.settings.batch))
        for a, b in list(itertools.pairwise(starts))[-checked:]:
            before = np.zeros(len(measured), dtype=bool)
            before[:a] = True
            fit_rows, new_rows = ok & before, ok & ~before
            new_rows[b:] = False
            if not new_rows.any():
                continue
            u_fit = joint_inputs(measured.d_um[fit_rows], measured.signs[fit_rows],
                                 measured.temperature_c[fit_rows], inputs)  # fmt: skip
            try:
                model = fit_adaptive_model(u_fit, inputs, measured.p_um[fit_rows], self.low_um,
                                           self.high_um, self.held_um)  # fmt: skip
            except DegenerateDataError:
                continue
            s2 = residual_variance_um2(model, u_fit, measured.p_um[fit_rows])
            u_new = joint_inputs(measured.d_um[new_rows], measured.signs[new_rows],
                                 measured.temperature_c[new_rows], inputs)  # fmt: skip
            r = measured.p_um[new_rows] - model.predict_um(u_new)
            m2.append((r**2 / (model.prediction_std_um(u_new) ** 2 + s2)).ravel())
        if not m2:
            return 1.0
        return float(np.mean(np.concatenate(m2)))

    def fit(self, measured: Measured) -> KinematicModel | None:
        """The design's model of the poses measured (None: too few to fit)."""
        ok = measured.ok
        inputs = self.inputs(measured)
        u = joint_inputs(measured.d_um[ok], measured.signs[ok], measured.temperature_c[ok],
                         inputs)  # fmt: skip
        try:
            return fit_adaptive_model(u, inputs, measured.p_um[ok], self.low_um, self.high_um,
                                      self.held_um)  # fmt: skip
        except DegenerateDataError:
            return None

    def fit_rows(self, u: FloatArray, inputs: tuple[str, ...], p_um: FloatArray) -> KinematicModel:
        """The design's model of (N, k) input rows (columns ``inputs``) and (N, 3) positions.

        Raises
        ------
        DegenerateDataError
            Too few rows.
        """
        return fit_adaptive_model(u, inputs, p_um, self.low_um, self.high_um, self.held_um)

    def planned_directions(self, measured: Measured, planned: int) -> FloatArray:
        """The approach directions chosen for the first ``planned`` poses (NaN: drawn), of
        which ``measured`` were measured: the batch not yet measured whole has its
        directions chosen again from the poses before it (the same choice, the next step
        being a function of them), (planned, 3)."""
        out = np.full((planned, 3), np.nan)
        starts = [a for a in self.batch_starts(planned) if a <= len(measured) and a < planned]
        if starts and self.settings.choose_directions:
            a = starts[-1]
            chosen = self.step(measured.head(a)).next_directions[: planned - a]
            out[a : a + len(chosen)] = chosen
        return out

    def direction_patterns(self) -> FloatArray:
        """Every combination of the moving joints' approach directions (a held joint's is
        +1), (P, 3)."""
        moving = self.low_um != self.high_um
        choices = [(-1.0, 1.0) if m else (1.0,) for m in moving]
        return np.array(list(itertools.product(*choices)), dtype=np.float64)

    def _taken(self, commanded_um: FloatArray) -> np.ndarray:
        """(C,) bool: candidates already commanded."""
        free = np.ones(len(self.candidates_um), dtype=bool)
        for d in commanded_um:
            free &= ~np.all(np.abs(self.candidates_um - d) < 1e-6, axis=1)
        return free

    def step(self, measured: Measured) -> AdaptiveStep:
        """The next batch, or the decision to stop, from the poses measured so far."""
        t0 = time.perf_counter()
        s = self.settings
        n = len(measured)
        ok = measured.ok
        inputs = self.inputs(measured)
        model = None
        figure = worst = float("nan")
        trusted = False
        inflation = 1.0
        try:
            u = joint_inputs(measured.d_um[ok], measured.signs[ok], measured.temperature_c[ok],
                             inputs)  # fmt: skip
            p = measured.p_um[ok]
            model = fit_adaptive_model(u, inputs, p, self.low_um, self.high_um, self.held_um)
            figure, worst = self.predicted_um(model, measured, inputs)
            inflation = float(np.sqrt(max(1.0, self.calibration(measured, inputs))))
            figure, worst = figure * inflation, worst * inflation
            edf = np.asarray(model.selection.get("edf", [0.0]), dtype=np.float64)
            trusted = bool(np.all(edf <= MAX_EDF_SHARE * len(u)))
        except DegenerateDataError:
            model = None
        level = f"{100 * s.level:.0f} %"
        if model is not None and trusted and figure <= s.until_um:
            return AdaptiveStep(n, int(ok.sum()), figure, worst, inflation, True,
                                f"predicted {level} error over the workspace {figure:.3g} µm <= "
                                f"{s.until_um:g} µm", np.zeros((0, 3)), model,
                                time.perf_counter() - t0)  # fmt: skip
        if n >= s.max_poses:
            return AdaptiveStep(n, int(ok.sum()), figure, worst, inflation, True,
                                f"{n} poses, the most allowed (predicted {level} error "
                                f"{figure:.3g} µm)", np.zeros((0, 3)), model,
                                time.perf_counter() - t0)  # fmt: skip
        count = min(s.batch, s.max_poses - n)
        free = self._taken(measured.d_um)
        c_um = self.candidates_um
        directions = np.full((count, 3), np.nan)
        if model is None:  # too few good poses to fit: the next candidates in Sobol order
            picks = np.flatnonzero(free)[:count].tolist()
        else:
            t_now = float(measured.temperature_c[ok][-1])
            patterns = self.direction_patterns() if s.choose_directions else None

            def inputs_for(i: int) -> FloatArray:
                if patterns is None:
                    return joint_inputs(c_um, self.signs_for(c_um, n + 1 + i), t_now, inputs)
                return np.vstack([joint_inputs(c_um, self.signs_for(c_um, n + 1 + i, w), t_now,
                                               inputs) for w in patterns])  # fmt: skip

            sigma2 = residual_variance_um2(model, u, p)
            last = measured.d_um[-1] if n else self.low_um
            k = 1 if patterns is None else len(patterns)
            rows = choose_batch(model, sigma2, self.test_inputs(measured, inputs), inputs_for,
                                count, last, np.tile(free, k), s.near_share, s.exchange,
                                np.tile(np.arange(len(c_um)), k))  # fmt: skip
            picks = [r % len(c_um) for r in rows]
            if patterns is not None:
                directions = patterns[[r // len(c_um) for r in rows]]
        reason = ("too few poses measured to fit" if model is None else
                  f"predicted {level} error over the workspace {figure:.3g} µm > "
                  f"{s.until_um:g} µm" if trusted or figure > s.until_um else
                  f"the fit follows the noise on some axis (more than {MAX_EDF_SHARE:.0%} of "
                  f"the poses in effective terms)")  # fmt: skip
        return AdaptiveStep(n, int(ok.sum()), figure, worst, inflation, False, reason,
                            c_um[picks], model, time.perf_counter() - t0,
                            directions[: len(picks)])  # fmt: skip


@dataclass
class AdaptiveResult:
    """An adaptive run: every pose measured, every step decided, and the last."""

    measured: Measured
    steps: list[AdaptiveStep] = field(default_factory=list)

    @property
    def final(self) -> AdaptiveStep:
        return self.steps[-1]

    @property
    def fit_s(self) -> float:
        """Wall time of every fit and choice, s."""
        return float(sum(st.fit_s for st in self.steps))


#: Acquires commands (N, 3) as the given 1-based poses, each approached in the directions
#: (N, 3) chosen for it (NaN: drawn as the acquisition does); returns their measurements.
Acquire = Callable[[FloatArray, list[int], FloatArray], Measured]


def run_adaptive(
    design: AdaptiveDesign,
    acquire: Acquire,
    measured: Measured | None = None,
    planned_um: FloatArray | None = None,
    on_plan: Callable[[FloatArray], None] | None = None,
    on_step: Callable[[AdaptiveStep], None] | None = None,
) -> AdaptiveResult:
    """Interleave acquisition and the design's steps until it stops.

    Parameters
    ----------
    design : AdaptiveDesign
    acquire : callable (commands (b, 3), poses) -> Measured
        Moves, settles and measures the poses (1-based numbers) given.
    measured : Measured, optional
        Poses already measured (a resumed run), in pose order from pose 1.
    planned_um : (N, 3) float, optional
        Commands already planned (a resumed run's commands); those not yet measured are
        acquired first. Default: the start design.
    on_plan : callable ((b, 3) float), optional
        Called with each new batch's commands before they are acquired (to store the plan).
    on_step : callable (AdaptiveStep), optional
    """
    have = measured if measured is not None else Measured.empty()
    plan = design.start_um() if planned_um is None else np.asarray(planned_um, dtype=np.float64)
    if planned_um is None and on_plan is not None and len(have) == 0:
        on_plan(plan)
    directions = design.planned_directions(have, len(plan))
    result = AdaptiveResult(have)
    while True:
        if len(plan) > len(result.measured):
            n = len(result.measured)
            poses = list(range(n + 1, len(plan) + 1))
            result.measured = result.measured + acquire(plan[n:], poses, directions[n:])
        step = design.step(result.measured)
        result.steps.append(step)
        if on_step is not None:
            on_step(step)
        if step.stop:
            return result
        if on_plan is not None:
            on_plan(step.next_um)
        plan = np.vstack([plan, step.next_um])
        directions = np.vstack([directions, step.next_directions])
