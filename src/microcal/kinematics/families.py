"""Families of polynomial-model candidate terms, and the choice among them by held-out error.

The thesis fits one family: the 30 terms of the quadratic polynomial, selected per axis by
stepwise F tests (:data:`FAMILIES` ``"quadratic"``). A manipulator's error need not lie in
that family: guideway straightness and angular errors seen at the tool (Abbe) are smooth
but not quadratic along each joint, and reversal error may change along the travel. The
richer families add

- ``cubic``: the monomials of degree 3 in the joints;
- ``waves``: the half-range cosine terms ``cos1 ... cos<k>`` along each joint, over the
  travel the model is identified on (:func:`~microcal.kinematics.terms.wave_terms`);
- for a model with the joints' approach directions (``sx, sy, sz``), the reversal error
  changing along the travel: ``sx*dx``, ``sy*dy``, ``sz*dz`` (sign times position);
- ``smooth``: the quadratic and the waves up to ``cos8``, none selected away: the waves'
  roughness is penalised instead, the smoothing chosen by GCV
  (:mod:`~microcal.kinematics.penalised`). Its covariance is a smoothing spline's Bayesian
  one, which covers the true error at about its stated rate.

The richer families take each extra input to the first power only (T, not T^2).

Within a family the terms are still selected stepwise. Which family (and which stepwise
threshold) a manipulator needs is chosen by k-fold cross-validation on the fitting poses
(:func:`choose_family`, ``family="auto"``): the candidate whose whole procedure, selection
included, predicts held-out poses best, unless a smaller one is within one standard error
of it (the one-standard-error rule, which prefers the simpler model when the data cannot
tell them apart).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError
from .models import KinematicModel, fit_model
from .penalised import fit_penalised_axis, roughness_weights
from .terms import JOINTS, Term, design_matrix, polynomial_terms, terms_without, wave_terms
from .validation import kfold_indices

__all__ = [
    "AUTO_CANDIDATES",
    "FAMILIES",
    "Family",
    "FamilyChoice",
    "choose_family",
    "family_terms",
    "fit_family",
]


@dataclass(frozen=True)
class Family:
    """A family of candidate terms.

    Attributes
    ----------
    name : str
    degree : int
        Highest total degree of the joint monomials.
    harmonics : int
        Half-range cosine harmonics per joint (0: none).
    penter : float
        Stepwise entry threshold (removal at twice it).
    penalised : bool
        Instead of stepwise selection, every term is kept and the waves' roughness is
        penalised, the smoothing chosen by GCV (:mod:`~microcal.kinematics.penalised`).
    """

    name: str
    degree: int = 2
    harmonics: int = 0
    penter: float = 0.05
    penalised: bool = False


#: The families by name. ``quadratic`` is the thesis's (Eq 4.6-4.10).
FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        Family("quadratic", 2, 0),
        Family("smooth", 2, 8, penalised=True),
        Family("cubic", 3, 0),
        Family("quadratic+waves", 2, 4),
        Family("cubic+waves", 3, 6),
        Family("cubic+waves-strict", 3, 6, 0.01),
    )
}

#: The candidates ``family="auto"`` chooses from, simplest first (``smooth``, shrunk, counts
#: as the simplest after the thesis's).
AUTO_CANDIDATES: tuple[str, ...] = ("quadratic", "smooth", "cubic", "quadratic+waves")

#: Folds of the cross-validation that chooses a family.
CHOICE_FOLDS = 5


def _approach_pairs(inputs: Sequence[str]) -> list[tuple[str, str]]:
    """(sign symbol, joint) pairs present among the inputs: ``("sx", "dx")`` ..."""
    return [(f"s{j[1:]}", j) for j in JOINTS if f"s{j[1:]}" in inputs and j in inputs]


def family_terms(
    family: Family,
    inputs: Sequence[str],
    extra: dict[str, int],
    joint_range_um: FloatArray,
) -> tuple[Term, ...]:
    """The candidate terms of a family for these inputs.

    Parameters
    ----------
    family : Family
    inputs : sequence of str
        Joints first (``dx, dy, dz``), then the extra inputs' symbols.
    extra : dict of symbol -> degree
        The extra inputs' highest powers (as :func:`polynomial_terms` takes them).
    joint_range_um : (3, 2) float
        The joints' [low, high] over which the waves are laid (a joint whose range is one
        value is held still and gets none).
    """
    if family.name != "quadratic":
        # a square of a sensed input (T^2) extrapolates wildly beyond the small range a run
        # sweeps (a few tenths of a degree): the richer families take its linear term only
        extra = dict.fromkeys(extra, 1)
    terms = list(polynomial_terms(JOINTS, family.degree, extra))
    constant = terms.pop()  # the constant goes last
    if family.harmonics:
        r = np.asarray(joint_range_um, dtype=np.float64)
        moving = r[:, 1] > r[:, 0]
        joints = [j for j, keep in zip(JOINTS, moving, strict=True) if keep]
        terms += wave_terms(joints, r[moving, 0].tolist(), r[moving, 1].tolist(), family.harmonics)
    if family.name != "quadratic":
        terms += [Term(((s, 1), (j, 1))) for s, j in _approach_pairs(inputs)]
    return (*terms, constant)


def fit_family(
    u: FloatArray,
    p_um: FloatArray,
    family: Family,
    inputs: Sequence[str],
    extra: dict[str, int],
    joint_range_um: FloatArray,
    held_um: dict[str, float] | None = None,
) -> KinematicModel:
    """Fit a family's terms, selected stepwise, to (N, k) inputs and (N, 3) positions.

    ``held_um``: joints the device holds still and their value (a two-axis positioner's
    missing axis, see :class:`~microcal.kinematics.models.KinematicModel`): no term uses
    them.
    """
    held = dict(held_um or {})
    terms = terms_without(family_terms(family, inputs, extra, joint_range_um), held)
    if family.penalised:
        return _fit_penalised(u, p_um, family, terms, inputs, held)
    model = fit_model(
        u,
        p_um,
        terms,
        kind="polynomial",
        inputs=inputs,
        select="stepwise",
        penter=family.penter,
        premove=2 * family.penter,
        held_um=held,
    )
    return dataclasses.replace(model, selection={**model.selection, "family": family.name})


def _fit_penalised(
    u: FloatArray,
    p_um: FloatArray,
    family: Family,
    terms: Sequence[Term],
    inputs: Sequence[str],
    held_um: dict[str, float],
) -> KinematicModel:
    U = np.asarray(u, dtype=np.float64)
    P = np.asarray(p_um, dtype=np.float64)
    X = design_matrix(U, inputs, terms)
    weights = roughness_weights([t.waves[0].harmonic if t.waves else 0 for t in terms])
    m = len(terms)
    coef, cov = np.zeros((3, m)), np.zeros((3, m, m))
    record: dict[str, object] = {"method": "penalised", "family": family.name, "n_samples": len(U)}
    lams, edfs = [], []
    for axis in range(3):
        fit = fit_penalised_axis(X, P[:, axis], weights)
        coef[axis], cov[axis] = fit.coef, fit.covariance
        lams.append(fit.lam)
        edfs.append(fit.edf)
    record |= {"lambda": lams, "edf": edfs}
    return KinematicModel("polynomial", tuple(inputs), JOINTS, tuple(terms), coef,
                          np.ones((3, m), dtype=bool), cov, record, held_um)  # fmt: skip


@dataclass(frozen=True)
class FamilyChoice:
    """The outcome of :func:`choose_family`."""

    family: Family
    #: Per candidate: mean and standard error of the held-out Euclidean error, µm.
    scores: dict[str, tuple[float, float]]

    def as_dict(self) -> dict[str, object]:
        """For the model's ``selection`` record."""
        return {
            "chosen_by": f"{CHOICE_FOLDS}-fold held-out error, one-standard-error rule",
            "family": self.family.name,
            "held_out_mean_um": {k: v[0] for k, v in self.scores.items()},
            "held_out_se_um": {k: v[1] for k, v in self.scores.items()},
        }


def choose_family(
    u: FloatArray,
    p_um: FloatArray,
    inputs: Sequence[str],
    extra: dict[str, int],
    joint_range_um: FloatArray,
    candidates: Sequence[str] = AUTO_CANDIDATES,
    seed: int = 0,
    held_um: dict[str, float] | None = None,
) -> FamilyChoice:
    """Choose a family by k-fold held-out error of its whole fit (selection included).

    Parameters
    ----------
    u : (N, k) float
    p_um : (N, 3) float
    candidates : sequence of str
        Names in :data:`FAMILIES`, smallest first (the one-standard-error rule prefers the
        earliest of those within one standard error of the best).

    Raises
    ------
    InputError
        An unknown family name.
    DegenerateDataError
        No candidate can be fitted on the folds (too few poses).
    """
    unknown = [c for c in candidates if c not in FAMILIES]
    if unknown:
        raise InputError(f"family: expected names of {sorted(FAMILIES)}, got {unknown}")
    n = u.shape[0]
    folds = kfold_indices(n, min(CHOICE_FOLDS, n), seed)
    scores: dict[str, tuple[float, float]] = {}
    for name in candidates:
        errors = np.empty(n)
        try:
            for fold in folds:
                train = np.setdiff1d(np.arange(n), fold)
                model = fit_family(
                    u[train], p_um[train], FAMILIES[name], inputs, extra, joint_range_um, held_um
                )
                errors[fold] = np.linalg.norm(model.predict_um(u[fold]) - p_um[fold], axis=1)
        except DegenerateDataError:
            continue
        scores[name] = (float(errors.mean()), float(errors.std(ddof=1) / np.sqrt(n)))
    if not scores:
        raise DegenerateDataError(
            f"family: no candidate of {list(candidates)} can be fitted on {n} poses in "
            f"{len(folds)} folds; acquire more poses"
        )
    best = min(scores, key=lambda k: scores[k][0])
    limit = scores[best][0] + scores[best][1]
    chosen = next(k for k in candidates if k in scores and scores[k][0] <= limit)
    return FamilyChoice(FAMILIES[chosen], scores)
