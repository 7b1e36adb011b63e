"""The adaptive command design: each next pose where the model is least sure, until the
predicted error of the compensated tip is below a tolerance everywhere in the workspace.

Every other design (:mod:`~microcal.kinematics.designs`) is fixed before the first pose is
measured. This one starts with a small space-filling design (scrambled Sobol), fits the
``smooth`` model (:mod:`~microcal.kinematics.families`: the quadratic, the waves along each
joint with their roughness penalised, the approach directions and the temperature), and
then adds batches of poses chosen from that fit:

- **Predicted error of the compensated tip.** The compensator drives the joints to where
  the model puts the target, so the tip misses by the model's error there: its covariance
  is the model's prediction covariance (the coefficients' Bayesian covariance propagated
  to the position, :meth:`~microcal.kinematics.models.KinematicModel.prediction_std_um`),
  plus the motion's own scatter. :func:`predicted_tip_error_um` gives the radius that holds
  the tip with probability ``level`` (the 95th percentile of the error's length), at test
  joints spread over the workspace (a regular grid, the corners and faces included), each
  approached from below as the fixed approach of the compensator does.
- **Criterion: the integral.** Each next pose is the candidate whose measurement would
  reduce the *summed* predicted variance over the test joints most (I-optimality; for a
  fit linear in its coefficients the reduction of adding a row ``z`` is
  ``sum_t (x_t S z)^2 / (s^2 + z S z)`` per axis, S the coefficients' covariance, s^2 the
  residual variance; after each pick S is updated by the Sherman-Morrison formula, so a
  batch spreads out). The integral, not the largest: the stopping rule looks at the largest,
  but greedy steps on the largest chase one corner at a time and leave the rest of the
  workspace where it was, while the integral lowers the whole map (the largest with it) and
  is what the percentile of the tip's error over the workspace measures.
- **Candidates**: scrambled Sobol joints over the workspace and a regular grid from its low
  to its high limits (``boundary_grid`` per axis: the corners, edges and faces, where a
  random or Sobol design is thinnest and a polynomial's variance largest).
- **Exchange**: after the greedy choice, each pose of the batch in turn is replaced by the
  candidate that reduces the summed variance most with the others kept (``exchange``
  passes, until none changes).
- **Varied approaches.** Each pose's approach directions are those the acquisition gives it
  (:func:`~microcal.procedures.acquisition.approach_start_um`: a side per joint drawn from
  the pose number), so a model with direction terms sees them vary; the candidates are
  scored with the directions their pose will have. ``near_share`` below 1 takes, among
  the candidates within that share of the best reduction, the one nearest the previous
  pose (shorter moves, more poses: 1 by default).
- **Stopping rule** (:mod:`~microcal.procedures.adaptive`): the predicted ``level`` error
  over the workspace is at most ``until_um`` (or the poses reach ``max_poses``).

Everything here is a deterministic function of the poses measured so far (their commands,
positions, approach directions and temperatures): a run stopped and resumed chooses the
same poses as one that was not.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.stats.qmc as qmc

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from .families import FAMILIES, fit_family
from .models import KinematicModel
from .terms import JOINTS, design_matrix

__all__ = [
    "ADAPTIVE",
    "ADAPTIVE_FAMILY",
    "AdaptiveSettings",
    "candidate_joints_um",
    "choose_batch",
    "fit_adaptive_model",
    "predicted_tip_error_um",
    "predicted_workspace_error_um",
    "prior_model",
    "residual_variance_um2",
    "start_design_um",
    "tip_error_draws_um",
    "workspace_grid_um",
]

#: The design's name (``--design adaptive``).
ADAPTIVE = "adaptive"
#: The model family the adaptive design fits and judges.
ADAPTIVE_FAMILY = "smooth"
#: Normal draws (fixed) that turn a per-axis variance into the radius holding ``level``.
_SAMPLES = np.random.default_rng(0).standard_normal((4000, 3))


@dataclass(frozen=True)
class AdaptiveSettings:
    """How an adaptive design starts, chooses and stops.

    Attributes
    ----------
    until_um : float
        Stop when the predicted ``level`` error of the compensated tip is at most this
        everywhere in the workspace, µm.
    max_poses : int
        Stop at this many poses in any case.
    start_poses : int
        The space-filling start (scrambled Sobol).
    batch : int
        Poses chosen per fit.
    level : float
        Probability content of the predicted error.
    candidates : int
        Candidate joints (scrambled Sobol over the workspace) each pose is chosen among.
    grid_per_axis : int
        Test joints per axis of the workspace grid the predicted error is judged on.
    near_share : float
        A candidate within this share of the best reduction may be taken for a shorter move
        (1: the best alone).
    seed : int
        Seed of the start design and of the candidates.
    boundary_grid : int
        The candidates also hold a regular grid of this many joints per axis from low to
        high (the corners, edges and faces of the workspace, where a random or Sobol design
        is thinnest and a polynomial's variance largest); below 2: none.
    exchange : int
        Passes of exchange over each batch after its greedy choice.
    choose_directions : bool
        The design chooses each pose's approach directions too (each candidate scored with
        every combination of the moving joints' directions); False: each pose keeps the
        directions the acquisition draws for it.
    start : {"sobol", "prior"}
        The start: scrambled Sobol joints, or the candidates that reduce the predicted
        variance over the workspace most under the smooth model's prior
        (:func:`prior_model`), chosen as every later batch is.
    """

    until_um: float
    max_poses: int = 400
    start_poses: int = 20
    batch: int = 5
    level: float = 0.95
    candidates: int = 2048
    grid_per_axis: int = 7
    near_share: float = 1.0
    seed: int = 0
    boundary_grid: int = 5
    exchange: int = 2
    choose_directions: bool = False
    start: str = "sobol"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.until_um) and self.until_um > 0):
            raise InputError(f"--until-um: expected a tolerance > 0 µm, got {self.until_um!r}")
        if self.start_poses < 12:
            raise InputError(f"start poses: expected 12 or more, got {self.start_poses}")
        if self.max_poses < self.start_poses:
            raise InputError(
                f"--max-poses: expected at least the {self.start_poses} poses of the start, got "
                f"{self.max_poses}"
            )
        if self.batch < 1 or not 0 < self.level < 1 or not 0 < self.near_share <= 1:
            raise InputError("batch >= 1, 0 < level < 1 and 0 < near_share <= 1 expected")


def _sobol(n: int, low: FloatArray, high: FloatArray, seed: int) -> FloatArray:
    moving = high > low
    with warnings.catch_warnings():  # balance is best at powers of 2; any n is still fine
        warnings.simplefilter("ignore", UserWarning)
        unit = qmc.Sobol(int(moving.sum()), scramble=True, seed=seed).random(n)
    out = np.broadcast_to(low, (n, low.size)).copy()
    out[:, moving] += unit * (high - low)[moving]
    return out


def start_design_um(
    settings: AdaptiveSettings, low_um: FloatArray, high_um: FloatArray
) -> FloatArray:
    """The space-filling start, (start_poses, 3) µm."""
    return _sobol(settings.start_poses, low_um, high_um, settings.seed)


def candidate_joints_um(
    settings: AdaptiveSettings, low_um: FloatArray, high_um: FloatArray
) -> FloatArray:
    """The joints every next pose is chosen among, (candidates, 3) µm."""
    sobol = _sobol(settings.candidates, low_um, high_um, settings.seed + 1)
    k = settings.boundary_grid
    if k < 2:
        return sobol
    axes = [np.linspace(lo, hi, k) if hi > lo else np.array([lo])
            for lo, hi in zip(low_um, high_um, strict=True)]  # fmt: skip
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    out: FloatArray = np.vstack([grid, sobol])
    return out


def workspace_grid_um(
    settings: AdaptiveSettings, low_um: FloatArray, high_um: FloatArray
) -> FloatArray:
    """The workspace's test joints: the centres of a grid of equal cells, so that each
    stands for as much of the workspace, (grid^k, 3) µm (a held joint stays at its one
    value)."""
    k = settings.grid_per_axis
    centres = (np.arange(k) + 0.5) / k
    axes = [lo + centres * (hi - lo) if hi > lo else np.array([lo])
            for lo, hi in zip(low_um, high_um, strict=True)]  # fmt: skip
    out: FloatArray = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return out


def fit_adaptive_model(
    u: FloatArray,
    inputs: Sequence[str],
    p_um: FloatArray,
    low_um: FloatArray,
    high_um: FloatArray,
    held_um: dict[str, float] | None = None,
) -> KinematicModel:
    """The ``smooth`` model of (N, k) inputs (columns ``inputs``, joints first) and (N, 3)
    positions, its waves laid over the workspace ``[low_um, high_um]`` (fixed, so that every
    fit of a run has the same terms).

    Raises
    ------
    DegenerateDataError
        Too few poses for its unpenalised terms.
    """
    extra = dict.fromkeys(inputs[3:], 1)
    workspace = np.column_stack([low_um, high_um])
    return fit_family(u, p_um, FAMILIES[ADAPTIVE_FAMILY], tuple(inputs), extra, workspace, held_um)


def residual_variance_um2(model: KinematicModel, u: FloatArray, p_um: FloatArray) -> FloatArray:
    """Each axis's residual variance ``RSS / (N - edf)`` of a fitted model, (3,) µm²."""
    r = p_um - model.predict_um(u)
    edf = np.asarray(model.selection.get("edf", model.selected.sum(axis=1)), dtype=np.float64)
    out: FloatArray = np.sum(r**2, axis=0) / np.maximum(u.shape[0] - edf, 1.0)
    return out


def tip_error_draws_um(
    model: KinematicModel, u: FloatArray, extra_var_um2: FloatArray | float
) -> FloatArray:
    """Draws (fixed) of the compensated tip's error length at each input, from the model's
    prediction variance plus ``extra_var_um2`` per axis, (M, S) µm."""
    var = model.prediction_std_um(u) ** 2 + np.asarray(extra_var_um2, dtype=np.float64)
    out: FloatArray = np.linalg.norm(_SAMPLES[None, :, :] * np.sqrt(var)[:, None, :], axis=2)
    return out


def predicted_tip_error_um(
    model: KinematicModel,
    u: FloatArray,
    extra_var_um2: FloatArray | float = 0.0,
    level: float = 0.95,
) -> FloatArray:
    """The radius holding the compensated tip with probability ``level``, (M,) µm.

    Parameters
    ----------
    u : (M, k) float
        Inputs (joints, then the model's extra inputs) where the tip is sent.
    extra_var_um2 : float or (3,) float
        Variance per axis to add (the motion's scatter), µm².
    """
    out: FloatArray = np.quantile(tip_error_draws_um(model, u, extra_var_um2), level, axis=1)
    return out


def predicted_workspace_error_um(
    model: KinematicModel,
    u: FloatArray,
    extra_var_um2: FloatArray | float = 0.0,
    level: float = 0.95,
) -> float:
    """The ``level`` quantile of the compensated tip's error over the whole workspace: a
    target anywhere in it (each of the M test inputs, standing for equal parts of it, as
    likely), its error drawn from the model's prediction there, µm."""
    return float(np.quantile(tip_error_draws_um(model, u, extra_var_um2), level))


#: The prior of :func:`prior_model`: the smoothing parameter (on terms scaled to unit root
#: mean square over the candidates) and the precision of the unpenalised terms.
PRIOR_LAMBDA = 0.3
PRIOR_FLAT = 1e-4


def prior_model(
    inputs: Sequence[str],
    low_um: FloatArray,
    high_um: FloatArray,
    u_scale: FloatArray,
    held_um: dict[str, float] | None = None,
) -> KinematicModel:
    """The smooth model before any pose: zero coefficients, and the covariance of its
    roughness penalty taken as a prior (a wave of harmonic k has variance
    ``1 / (PRIOR_LAMBDA k^4)`` in units of the noise, a term without a wave is all but
    free), on terms scaled by their root mean square over the inputs ``u_scale`` (N, k)."""
    from .families import family_terms
    from .penalised import roughness_weights
    from .terms import terms_without

    extra = dict.fromkeys(inputs[3:], 1)
    workspace = np.column_stack([low_um, high_um])
    terms = terms_without(family_terms(FAMILIES[ADAPTIVE_FAMILY], tuple(inputs), extra,
                                       workspace), held_um or {})  # fmt: skip
    X = design_matrix(u_scale, tuple(inputs), terms)
    scale = np.sqrt(np.mean(X**2, axis=0))
    scale[scale == 0] = 1.0
    w = roughness_weights([t.waves[0].harmonic if t.waves else 0 for t in terms])
    var = 1.0 / (PRIOR_LAMBDA * w + PRIOR_FLAT) / scale**2
    m = len(terms)
    cov = np.broadcast_to(np.diag(var), (3, m, m)).copy()
    return KinematicModel("polynomial", tuple(inputs), JOINTS, tuple(terms), np.zeros((3, m)),
                          np.ones((3, m), dtype=bool), cov, {"method": "prior"},
                          dict(held_um or {}))  # fmt: skip


def _design_rows(model: KinematicModel, u: FloatArray) -> FloatArray:
    X: FloatArray = design_matrix(u, model.inputs, model.terms)
    return X


def choose_batch(
    model: KinematicModel,
    sigma2_um2: FloatArray,
    u_test: FloatArray,
    inputs_for: Callable[[int], FloatArray],
    count: int,
    start_um: FloatArray,
    available: np.ndarray,
    near_share: float = 0.8,
    exchange: int = 0,
    group: np.ndarray | None = None,
) -> list[int]:
    """Candidates for the next ``count`` poses, chosen one after the other (module docstring).

    Parameters
    ----------
    model : KinematicModel
        The current fit (its coefficients' covariance is updated as poses are chosen).
    sigma2_um2 : (3,) float
        Residual variance per axis (:func:`residual_variance_um2`).
    u_test : (M, k) float
        The inputs the predicted error is judged at.
    inputs_for : callable (i) -> (C, k) float
        The candidates' inputs as the i-th pose of the batch (their approach directions
        depend on the pose).
    count : int
    start_um : (3,) float
        The joints before the batch (the last pose).
    available : (C,) bool
        Candidates not yet taken.
    exchange : int
        Passes of exchange after the greedy choice: each pose of the batch in turn is
        replaced by the candidate that reduces the summed variance most with the others kept.
    group : (C,) int, optional
        Candidates of one group are one joint (scored with different approach
        directions): taking one takes them all. Default: each its own.

    Returns
    -------
    list of int
        Candidate indices, in the order to visit them.
    """
    if not np.any(available):
        raise DegenerateDataError("adaptive design: every candidate has been taken")
    T = _design_rows(model, u_test)
    S0 = np.array(model.covariance, dtype=np.float64)
    S = S0.copy()
    s2 = np.maximum(np.asarray(sigma2_um2, dtype=np.float64), 1e-12)
    free = np.array(available, dtype=bool)
    groups = np.arange(free.size) if group is None else np.asarray(group)
    last = np.asarray(start_um, dtype=np.float64)
    chosen: list[int] = []
    rows: list[FloatArray] = []
    for i in range(count):
        if not np.any(free):
            break
        u_c = inputs_for(i)
        Z = _design_rows(model, u_c)
        rows.append(Z)
        gain = _gain(T, S, Z, s2)
        gain[~free] = -np.inf
        best = float(gain.max())
        near = np.flatnonzero(free & (gain >= near_share * best))
        move = np.max(np.abs(u_c[near, :3] - last), axis=1)
        pick = int(near[np.argmin(move)])
        chosen.append(pick)
        free[groups == groups[pick]] = False
        _add(S, Z[pick], s2)
        last = u_c[pick, :3]
    for _ in range(exchange):  # each pose again, the others kept: the best candidate for it
        changed = False
        for i in range(len(chosen)):
            S = S0.copy()
            for j, c in enumerate(chosen):
                if j != i:
                    _add(S, rows[j][c], s2)
            gain = _gain(T, S, rows[i], s2)
            own = groups == groups[chosen[i]]  # its joint with other directions may replace it
            gain[~(free | own)] = -np.inf
            gain[chosen[i]] = _gain(T, S, rows[i][chosen[i]][None, :], s2)[0]
            pick = int(np.argmax(gain))
            if pick != chosen[i] and gain[pick] > gain[chosen[i]] * (1 + 1e-9):
                free[own] = True
                free[groups == groups[pick]] = False
                chosen[i], changed = pick, True
        if not changed:
            break
    return chosen


def _gain(T: FloatArray, S: FloatArray, Z: FloatArray, s2: FloatArray) -> FloatArray:
    """(C,) the summed variance reduction over the test rows ``T`` (M, m) of measuring
    each candidate row of ``Z`` (C, m), given the coefficients' covariance ``S`` (3, m, m)
    and residual variance ``s2`` (3,)."""
    gain = np.zeros(Z.shape[0])
    for a in range(3):
        cross = (T @ S[a]) @ Z.T  # (M, C): x_t S z
        q = np.sum((Z @ S[a]) * Z, axis=1)
        gain += np.sum(cross**2, axis=0) / (s2[a] + q)
    return gain


def _add(S: FloatArray, z: FloatArray, s2: FloatArray) -> None:
    """Update the covariance ``S`` (3, m, m) in place for one more row ``z`` (Sherman-
    Morrison)."""
    for a in range(3):
        Sz = S[a] @ z
        S[a] -= np.outer(Sz, Sz) / (s2[a] + float(z @ Sz))


def joint_inputs(
    d_um: FloatArray, signs: FloatArray, temperature_c: FloatArray | float, inputs: Sequence[str]
) -> FloatArray:
    """(N, len(inputs)) input columns for joints, approach directions (N, 3) and a
    temperature, in the order of ``inputs`` (joints, then any of ``sx, sy, sz, T``)."""
    n = d_um.shape[0]
    t = np.broadcast_to(np.asarray(temperature_c, dtype=np.float64), (n,))
    by_name = {**{j: d_um[:, k] for k, j in enumerate(JOINTS)},
               **{f"s{a}": signs[:, k] for k, a in enumerate("xyz")}, "T": t}  # fmt: skip
    missing = [name for name in inputs if name not in by_name]
    if missing:
        raise InputError(f"adaptive design: no values for the inputs {missing}")
    out: FloatArray = np.column_stack([by_name[name] for name in inputs])
    return out
