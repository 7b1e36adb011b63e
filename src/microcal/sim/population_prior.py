"""A reference for how close to the oracle a model can come on a ``population`` platform:
kriging with the draw's own prior.

A model identified from measurements is compared with the oracle (the truth, its
known-form parts re-estimated from the same measurements). The oracle knows each joint's
straightness and angular profiles exactly; a model has to estimate them from the poses.
The Bayes estimator under the population's prior shows what that costs: each axis's error
is the oracle's known-form terms (flat prior) plus, per joint, a zero-mean Gaussian process
with the very length scale and variance the draw's profiles came from
(:class:`~microcal.sim.population.PopulationDraw`), plus the measurement noise and the
sensors' periodic error as white noise. It knows the draw's hyperparameters (length
scales, deviations, tool offset, periodic amplitudes), not its profiles. Its posterior
mean (universal kriging) has the least expected squared prediction error, over the draws
of that prior, of any estimator from the same measurements: a reference on average, not a
bound on every figure of every draw (AP after inversion, at eight poses, is another
figure).

Three simplifications keep it per axis, each in the estimator's disfavour by a little: the
Abbe errors of one joint are correlated across the axes (one rotation, seen at the tool),
which a per-axis prior leaves unused; the measurement noise is taken per axis (its
covariance's diagonal; triangulation correlates the axes); and the periodic error is
treated as noise. Simulator only: a real manipulator's prior is not known.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve

from .._validation import FloatArray
from ..errors import InputError
from ..kinematics.terms import JOINTS, Term, design_matrix, polynomial_terms
from .population import PopulationDraw

__all__ = ["PriorEstimator", "fit_prior_estimator", "known_form_terms", "profile_variance_um2"]


def known_form_terms(inputs: Sequence[str]) -> list[Term]:
    """The terms of the truth's known form: the quadratic in the joints, each extra input
    of ``inputs`` (approach signs ``sx, sy, sz``, temperature ``T``) to the first power, the
    reversal's change along the travel (``sx*dx`` ...) and the constant, last."""
    extra = dict.fromkeys([n for n in inputs if n not in JOINTS], 1)
    terms = list(polynomial_terms(JOINTS, 2, extra))
    constant = terms.pop()
    terms += [Term(((f"s{j[1]}", 1), (j, 1))) for j in JOINTS if f"s{j[1]}" in inputs]
    return [*terms, constant]


def profile_variance_um2(draw: PopulationDraw) -> FloatArray:
    """Prior variance of joint j's profile along axis a, (3 axes, 3 joints) µm².

    Straightness moves the tool in the two axes other than the joint's own; a rotation w of
    the carriage, each component of sd ``angle_sd_urad``, moves it by ``w x r`` (r the tool
    offset), whose component a has variance ``sd^2 (|r|^2 - r_a^2)``.
    """
    errors = draw.truth.joint_errors
    if errors is None:
        raise InputError("population draw: expected joint errors, got none")
    r2 = errors.tool_offset_um**2
    abbe = (1e-6 * draw.angle_sd_urad[None, :]) ** 2 * (r2.sum() - r2)[:, None]
    straight = draw.straightness_sd_um[None, :] ** 2 * (1.0 - np.eye(3))
    out: FloatArray = straight + abbe
    return out


@dataclass(frozen=True)
class PriorEstimator:
    """The posterior mean of each axis's map, fitted by :func:`fit_prior_estimator`.

    Attributes
    ----------
    inputs : tuple of str
        The input columns, joints first.
    terms : tuple of Term
        The known-form terms.
    coefficients : (3, m) float
        Their generalised least-squares coefficients, per axis.
    weights : (3, N) float
        Per axis, ``K^-1 (y - X b)``: the kriging weights of the training poses.
    joints_um : (N, 3) float
        The training poses' joints.
    length_um : (3,) float
        Each joint's length scale.
    variance_um2 : (3, 3) float
        :func:`profile_variance_um2`.
    """

    inputs: tuple[str, ...]
    terms: tuple[Term, ...]
    coefficients: FloatArray
    weights: FloatArray
    joints_um: FloatArray
    length_um: FloatArray
    variance_um2: FloatArray

    def predict_um(self, u: FloatArray) -> FloatArray:
        """Posterior mean at (M, k) inputs (columns as ``inputs``), (M, 3) µm."""
        u = np.asarray(u, dtype=np.float64)
        X = design_matrix(u, self.inputs, self.terms)
        corr = _correlations(u[:, :3], self.joints_um, self.length_um)
        out = np.empty((u.shape[0], 3))
        for a in range(3):
            k = np.tensordot(self.variance_um2[a], corr, axes=1)  # (M, N)
            out[:, a] = X @ self.coefficients[a] + k @ self.weights[a]
        return out


def _correlations(d1_um: FloatArray, d2_um: FloatArray, length_um: FloatArray) -> FloatArray:
    """Squared-exponential correlation of each joint between (M, 3) and (N, 3), (3, M, N)."""
    diff = (d1_um.T[:, :, None] - d2_um.T[:, None, :]) / length_um[:, None, None]
    out: FloatArray = np.exp(-0.5 * diff**2)
    return out


def fit_prior_estimator(
    draw: PopulationDraw,
    u: FloatArray,
    inputs: Sequence[str],
    p_um: FloatArray,
    noise_var_um2: FloatArray,
) -> PriorEstimator:
    """Kriging of each axis under the draw's own prior (see the module docstring).

    Parameters
    ----------
    draw : PopulationDraw
        The platform's draw (``SimPlatform.population``).
    u : (N, k) float
        Inputs, columns as ``inputs`` (joints first).
    p_um : (N, 3) float
        Measured positions.
    noise_var_um2 : (N, 3) float
        Each measurement's noise variance per axis.
    """
    names = tuple(inputs)
    if names[:3] != JOINTS:
        raise InputError(f"inputs: expected the joints {JOINTS} first, got {names}")
    u = np.asarray(u, dtype=np.float64)
    p = np.asarray(p_um, dtype=np.float64)
    noise = np.asarray(noise_var_um2, dtype=np.float64)
    if p.shape != (u.shape[0], 3) or noise.shape != p.shape:
        raise InputError(
            f"p_um, noise_var_um2: expected ({u.shape[0]}, 3) each, got {p.shape}, {noise.shape}"
        )
    errors = draw.truth.joint_errors
    assert errors is not None
    terms = tuple(known_form_terms(names))
    X = design_matrix(u, names, terms)
    scale = np.linalg.norm(X, axis=0)  # columns from 1 to ~1e7 µm²: solved scaled
    scale[scale == 0] = 1.0
    Xs = X / scale
    d = u[:, :3]
    corr = _correlations(d, d, draw.profile_length_um)
    variance = profile_variance_um2(draw)
    periodic = errors.periodic_um**2 / 2  # along each joint's own axis
    coef = np.empty((3, len(terms)))
    weights = np.empty((3, u.shape[0]))
    for a in range(3):
        K = np.tensordot(variance[a], corr, axes=1)
        K[np.diag_indices_from(K)] += noise[:, a] + periodic[a]
        chol = np.linalg.cholesky(K)
        Kx = _solve(chol, Xs)
        coef[a] = np.linalg.solve(Xs.T @ Kx, Kx.T @ p[:, a]) / scale
        weights[a] = _solve(chol, p[:, a] - X @ coef[a])
    return PriorEstimator(names, terms, coef, weights, d.copy(),
                          draw.profile_length_um.copy(), variance)  # fmt: skip


def _solve(chol: FloatArray, b: FloatArray) -> FloatArray:
    """``K^-1 b`` from the Cholesky factor of K."""
    out: FloatArray = cho_solve((chol, True), b)
    return out
