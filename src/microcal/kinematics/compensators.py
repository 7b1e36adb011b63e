"""Compensators: joint commands that put the end-effector at a desired position (thesis 4.4).

- :func:`matrix_compensator` inverts the matrix model (Eq 4.16) by solving ``R d = p - P_B``
  (a linear solve, not the adjugate formula the thesis wrote out).
- :func:`optimal_compensator` solves ``F(d) = model(d) - p = 0`` (Eq 4.17-4.19) for any
  model of the term library, vectorised over N targets: Newton steps with the analytic
  Jacobian, started from the solution of the model's linear part, each step accepted only if
  it lowers the residual (halved otherwise); targets that still fail get a
  Levenberg-Marquardt solve of their own. Extra inputs (temperature) are given, not solved.

A target whose joints would leave the soft limits is refused with :class:`LimitError`; a
solution is never clipped.

A model with **held joints** (a two-axis X-Y positioner: its third joint is held at one value,
see :class:`~microcal.kinematics.models.KinematicModel`) reaches only a surface of {G}: the
compensator solves for the moving joints in the least-squares sense (Gauss-Newton), so a
target off that surface gets the surface's nearest point, and ``residual_um`` is the
distance left; the held joints are set to their values.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows, check_limits
from ..errors import DegenerateDataError, InputError
from .compensator_paths import CHUNK, PlanarNewton, ScalarNewton
from .extra_inputs import default_extra_inputs
from .models import KinematicModel, _Compiled

__all__ = [
    "MAX_CONDITION",
    "Compensation",
    "Compensator",
    "matrix_compensator",
    "optimal_compensator",
]

#: A linear part whose condition number exceeds this cannot be inverted reliably.
MAX_CONDITION = 1e6


@dataclass(frozen=True)
class Compensation:
    """Joint commands for N targets and how well they solve the model."""

    d_um: FloatArray  # (N, j) joint commands
    converged: np.ndarray  # (N,) bool
    residual_um: FloatArray  # (N,) |model(d) - p| (with held joints: distance off the surface)
    iterations: int  # Newton iterations taken by the batch
    n_fallback: int  # targets solved by the Levenberg-Marquardt fallback


def _linear_part(model: KinematicModel, extra: FloatArray) -> tuple[FloatArray, FloatArray]:
    """R (3, j) and the offset (N, 3) of the model's terms that are not joint-dependent."""
    R = model.R  # (3, j) by construction
    j = len(model.joints)
    if j != 3:
        raise InputError(f"compensator: expected a model with 3 joints, got {list(model.joints)}")
    moving = [model.joints.index(name) for name in model.moving_joints]
    cond = np.linalg.cond(R[:, moving])
    if not np.isfinite(cond) or cond > MAX_CONDITION:
        raise DegenerateDataError(
            f"compensator: the model's linear part R is singular or ill-conditioned "
            f"(condition number {cond:.3g} > {MAX_CONDITION:.0e}); the joints cannot be solved "
            f"for - was every axis moved during identification?"
        )
    return R, _offset(model, extra)


def _offset(model: KinematicModel, extra: FloatArray) -> FloatArray:
    """The terms without joints (the constant and the powers of extra inputs), (N, 3)."""
    n, j = extra.shape[0], len(model.joints)
    offset = np.zeros((n, 3))
    u0 = np.hstack([np.broadcast_to(model.rest_um, (n, j)), extra])
    mask = np.array([not set(t.inputs) & set(model.joints) for t in model.terms])
    if mask.any():
        from .terms import design_matrix

        X = design_matrix(
            u0, model.inputs, [t for t, keep in zip(model.terms, mask, strict=True) if keep]
        )
        offset = X @ model.coefficients[:, mask].T
    return offset


def _extra_inputs(model: KinematicModel, n: int, extra: ArrayLike | None) -> FloatArray:
    names = model.extra_inputs
    if not names:
        if extra is not None and np.size(extra):
            raise InputError(f"extra: this model has no inputs besides the joints, got {extra}")
        return np.zeros((n, 0))
    if extra is None:
        return np.broadcast_to(default_extra_inputs(names), (n, len(names)))
    e = np.asarray(extra, dtype=np.float64)
    if e.ndim == 0 or e.shape == (len(names),):
        e = np.broadcast_to(e.reshape(1, -1), (n, len(names)))
    return as_array(e, "extra", (n, len(names)))


def _solve3(J: FloatArray, r: FloatArray) -> FloatArray:
    """Solve ``J x = r`` for N 3x3 systems at once.

    Few systems: LAPACK through ``numpy.linalg.solve`` (one call). Many: Cramer's rule over
    arrays, a few dozen vectorised operations however large N is (the Jacobians here are
    close to the identity, so the explicit determinant is harmless).
    """
    if r.shape[0] < 256:
        return np.asarray(np.linalg.solve(J, r[:, :, None])[:, :, 0], dtype=np.float64)
    # the nine entries as contiguous planes (one copy; strided columns cost more)
    a, b, c, d, e, f, g, h, i = np.ascontiguousarray(J.reshape(-1, 9).T)
    A = e * i - f * h
    B = f * g - d * i
    C = d * h - e * g
    det = a * A + b * B + c * C
    x = np.empty_like(r)
    r0, r1, r2 = r[:, 0], r[:, 1], r[:, 2]
    x[:, 0] = (A * r0 + (c * h - b * i) * r1 + (b * f - c * e) * r2) / det
    x[:, 1] = (B * r0 + (a * i - c * g) * r1 + (c * d - a * f) * r2) / det
    x[:, 2] = (C * r0 + (b * g - a * h) * r1 + (a * e - b * d) * r2) / det
    return x


def _least_squares(J: FloatArray, r: FloatArray) -> FloatArray:
    """Solve ``J x = r`` in the least-squares sense for N systems of 3 equations in k < 3
    unknowns at once (normal equations; J (N, 3, k) is well conditioned, its columns near
    unit vectors)."""
    A = np.einsum("nij,nik->njk", J, J)
    b = np.einsum("nij,ni->nj", J, r)
    return np.asarray(np.linalg.solve(A, b[:, :, None])[:, :, 0], dtype=np.float64)


class Compensator:
    """A model prepared for repeated inversion: compiled, and its linear part checked, once.

    Parameters
    ----------
    model : KinematicModel
        Joints dx, dy, dz; any terms. Held joints (``model.held_um``) are set to their
        values and the others solved for in the least-squares sense.
    limits_um : (3, 2) float, optional
        Soft limits (low, high) per joint; solutions outside raise LimitError.

    Raises
    ------
    DegenerateDataError
        If the model's linear part is singular or ill-conditioned.
    """

    def __init__(self, model: KinematicModel, limits_um: ArrayLike | None = None) -> None:
        self.model = model
        self.limits_um = None if limits_um is None else as_array(limits_um, "limits_um", (3, 2))
        self._R, _ = _linear_part(model, np.zeros((1, len(model.extra_inputs))))
        self._constant_only = not model.extra_inputs
        self._p_base = model.p_base_um
        used = np.asarray(model.selected.any(axis=0), dtype=bool)
        waves = [
            w for t, keep in zip(model.terms, used.tolist(), strict=True) if keep for w in t.waves
        ]
        self._waves = bool(waves)
        middle = np.zeros(3)
        for j, joint in enumerate(model.joints[:3]):
            mids = [(w.low + w.high) / 2 for w in waves if w.input == joint]
            middle[j] = mids[0] if mids else model.held_um.get(joint, 0.0)
        self._wave_middle = middle
        self._moving = np.array([j in model.moving_joints for j in model.joints])
        self._held = model.rest_um
        # the fast paths: a model of powers alone, every joint moving
        compiled = model._compiled
        self._planar: PlanarNewton | None = None
        self._scalar: ScalarNewton | None = None
        if isinstance(compiled, _Compiled) and bool(self._moving.all()) and not self._waves:
            self._planar = PlanarNewton(compiled.exps, compiled.coef, self._R)
            self._scalar = ScalarNewton(compiled.exps, compiled.coef, self._R)

    def _step(self, J: FloatArray, r: FloatArray) -> FloatArray:
        """The joint step (N, 3) that solves ``J step = r``: exactly for three moving joints,
        by least squares over the moving ones (the held ones do not move) otherwise."""
        if self._moving.all():
            return _solve3(J, r)
        step = np.zeros((r.shape[0], 3))
        step[:, self._moving] = _least_squares(J[:, :, self._moving], r)
        return step

    def _start(self, p: FloatArray, e: FloatArray) -> FloatArray:
        if self._waves:
            # wave terms are not zero at zero joints and share their span with the powers:
            # start from the model linearised at the middle of its waves' intervals
            u0 = np.hstack([np.broadcast_to(self._wave_middle, (p.shape[0], 3)), e])
            J0 = self.model.jacobian(u0)
            r0 = p - self.model.predict_um(u0)
            return np.asarray(u0[:, :3] + self._step(J0, r0), dtype=np.float64)
        # (R was checked once, in __init__)
        offset = self._p_base if self._constant_only else _offset(self.model, e)
        if self._moving.all():
            return np.asarray(np.linalg.solve(self._R, (p - offset).T).T, dtype=np.float64)
        d = np.broadcast_to(self._held, (p.shape[0], 3)).copy()
        R = self._R[:, self._moving]
        rhs = (p - offset).T - self._R[:, ~self._moving] @ self._held[~self._moving, None]
        d[:, self._moving] = np.linalg.lstsq(R, rhs, rcond=None)[0].T
        return d

    def linear(self, p_um: ArrayLike, *, extra: ArrayLike | None = None) -> FloatArray:
        """Joints from the linear part alone, ``R^-1 (p - P_B)`` (Eq 4.16); (N, 3)."""
        p = as_rows(p_um, "p_um", 3)
        e = _extra_inputs(self.model, p.shape[0], extra)
        d = self._start(p, e)
        if self.limits_um is not None:
            check_limits(d, self.limits_um, row="target", targets_um=p)
        return d

    def solve(
        self,
        p_um: ArrayLike,
        *,
        extra: ArrayLike | None = None,
        tol_um: float = 1e-9,
        max_iter: int = 20,
    ) -> Compensation:
        """Solve the whole model for the joints (Eq 4.17-4.19); see :func:`optimal_compensator`."""
        p = as_rows(p_um, "p_um", 3)
        n = p.shape[0]
        e = _extra_inputs(self.model, n, extra)
        if n == 1 and self._scalar is not None:
            one = self._solve_one(p, e, tol_um, max_iter)
            if one is not None:
                return one
        fast = self._solve_fast(p, e, tol_um, max_iter)
        if fast is not None:
            return fast
        return self._solve_general(p, e, self._start(p, e), tol_um, max_iter)

    def _solve_one(
        self, p: FloatArray, e: FloatArray, tol_um: float, max_iter: int
    ) -> Compensation | None:
        """One target by :class:`~.compensator_paths.ScalarNewton`; None if it gives up."""
        assert self._scalar is not None
        pp, ee = p[0].tolist(), e[0].tolist()
        one = self._scalar.solve(pp, ee, self._scalar.start(pp, ee), tol_um, max_iter)
        if one is None:
            return None
        joints, res, iterations = one
        d = np.array([joints])
        if self.limits_um is not None:
            check_limits(d, self.limits_um, row="target", targets_um=p)
        return Compensation(d, np.array([True]), np.array([res]), iterations, 0)

    def _solve_fast(
        self, p: FloatArray, e: FloatArray, tol_um: float, max_iter: int
    ) -> Compensation | None:
        """The Newton steps of :meth:`solve` by the fast paths (:mod:`.compensator_paths`),
        None where the model has none; a chunk (or the one target) they give up on is
        solved by the general path."""
        if self._planar is None or self._scalar is None:
            return None
        n = p.shape[0]
        if n == 1:
            return None  # one target that the scalar path gave up on: the general path
        else:
            d_out, norm = np.empty((n, 3)), np.empty(n)
            iterations, n_fallback = 0, 0
            for s in range(0, n, CHUNK):
                part = slice(s, s + CHUNK)
                got = self._planar.solve(p[part].T, e[part].T, tol_um, max_iter)
                if got is None:
                    start = self._start(p[part], e[part])
                    general = self._solve_general(
                        p[part], e[part], start, tol_um, max_iter, limits=False
                    )
                    d_out[part], norm[part] = general.d_um, general.residual_um
                    iterations = max(iterations, general.iterations)
                    n_fallback += general.n_fallback
                else:
                    d_out[part], norm[part] = got[0].T, got[1]
                    iterations = max(iterations, got[2])
            out = Compensation(d_out, norm <= tol_um, norm, iterations, n_fallback)
        if self.limits_um is not None:
            ok = out.converged
            check_limits(out.d_um[ok], self.limits_um, row="target", targets_um=p[ok])
        return out

    def _solve_general(
        self,
        p: FloatArray,
        e: FloatArray,
        d: FloatArray,
        tol_um: float,
        max_iter: int,
        limits: bool = True,
    ) -> Compensation:
        """:meth:`solve`'s Newton steps for any model: backtracking, then a
        Levenberg-Marquardt solve per target that still fails. ``limits``: check the
        solutions against the soft limits (a chunk of a batch leaves it to the batch)."""
        compiled = self.model._compiled

        def residual(dd: FloatArray, ee: FloatArray, pp: FloatArray) -> FloatArray:
            uu = dd if ee.shape[1] == 0 else np.hstack([dd, ee])
            out: FloatArray = compiled.predict(uu) - pp
            return out

        def jacobian(dd: FloatArray, ee: FloatArray) -> FloatArray:
            return compiled.jacobian(dd if ee.shape[1] == 0 else np.hstack([dd, ee]))

        if not self._moving.all():
            return self._solve_surface(p, e, d, residual, jacobian, tol_um, max_iter)
        r = residual(d, e, p)
        norm = np.sqrt(np.einsum("ij,ij->i", r, r))
        active = norm > tol_um
        iterations = 0
        while active.any() and iterations < max_iter:
            iterations += 1
            if active.all():  # the usual case: no index bookkeeping
                trial = d - _solve3(jacobian(d, e), r)
                r_trial = residual(trial, e, p)
                n_trial = np.sqrt(np.einsum("ij,ij->i", r_trial, r_trial))
                if np.all(n_trial < norm):
                    d, r, norm = trial, r_trial, n_trial
                    active = norm > tol_um
                    continue
            idx = np.flatnonzero(active)
            step = -_solve3(jacobian(d[idx], e[idx]), r[idx])
            for _ in range(6):  # backtracking: halve the step where it does not help
                trial = d[idx] + step
                r_trial = residual(trial, e[idx], p[idx])
                n_trial = np.sqrt(np.einsum("ij,ij->i", r_trial, r_trial))
                better = np.isfinite(n_trial) & (n_trial < norm[idx])
                take = idx[better]
                d[take], r[take], norm[take] = trial[better], r_trial[better], n_trial[better]
                if better.all():
                    break
                idx, step = idx[~better], step[~better] / 2.0
            active = norm > tol_um
        n_fallback = 0
        for i in np.flatnonzero(active):
            n_fallback += 1
            sol = scipy.optimize.least_squares(
                lambda x, i=i: residual(x[None, :], e[i : i + 1], p[i : i + 1])[0],
                d[i],
                jac=lambda x, i=i: jacobian(x[None, :], e[i : i + 1])[0],
                method="lm",
                xtol=1e-15,
                ftol=1e-15,
                gtol=1e-15,
            )
            res = float(np.linalg.norm(sol.fun))
            if res < norm[i]:
                d[i], norm[i] = sol.x, res
        converged = norm <= tol_um
        if limits and self.limits_um is not None:
            check_limits(d[converged], self.limits_um, row="target", targets_um=p[converged])
        return Compensation(d, converged, norm, iterations, n_fallback)

    def _solve_surface(
        self,
        p: FloatArray,
        e: FloatArray,
        d: FloatArray,
        residual: Callable[[FloatArray, FloatArray, FloatArray], FloatArray],
        jacobian: Callable[[FloatArray, FloatArray], FloatArray],
        tol_um: float,
        max_iter: int,
    ) -> Compensation:
        """Gauss-Newton over the moving joints: the surface's point nearest each target.

        A target has converged when its last step moved no joint by more than ``tol_um``;
        its residual is then its distance from the surface the model reaches.
        """
        r = residual(d, e, p)
        norm = np.sqrt(np.einsum("ij,ij->i", r, r))
        active = np.ones(p.shape[0], dtype=bool)
        iterations = 0
        while active.any() and iterations < max_iter:
            iterations += 1
            idx = np.flatnonzero(active)
            step = -self._step(jacobian(d[idx], e[idx]), r[idx])
            for _ in range(6):  # backtracking: halve the step where the residual grows
                trial = d[idx] + step
                r_trial = residual(trial, e[idx], p[idx])
                n_trial = np.sqrt(np.einsum("ij,ij->i", r_trial, r_trial))
                better = np.isfinite(n_trial) & (n_trial <= norm[idx] * (1 + 1e-12) + 1e-12)
                take = idx[better]
                d[take], r[take], norm[take] = trial[better], r_trial[better], n_trial[better]
                active[take] = np.abs(step[better]).max(axis=1) > tol_um
                if better.all():
                    break
                idx, step = idx[~better], step[~better] / 2.0
        converged = ~active
        if self.limits_um is not None:
            check_limits(d[converged], self.limits_um, row="target", targets_um=p[converged])
        return Compensation(d, converged, norm, iterations, 0)


def matrix_compensator(
    model: KinematicModel,
    p_um: ArrayLike,
    *,
    extra: ArrayLike | None = None,
    limits_um: ArrayLike | None = None,
) -> FloatArray:
    """Joint commands from the model's linear part: ``d = R^-1 (p - P_B)`` (Eq 4.16).

    Exact for the matrix model; for a polynomial model it ignores the nonlinear terms (it is
    the optimal compensator's starting point).

    Parameters
    ----------
    model : KinematicModel
    p_um : (N, 3) or (3,) float
        Desired positions in {G}, µm.
    extra : float or (N, e) float, optional
        Values of the model's extra inputs (temperature), if it has any; left out, each
        approach direction is +1 (a model with other inputs then needs them).
    limits_um : (3, 2) float, optional
        Soft limits (low, high) per joint; targets outside raise LimitError.

    Returns
    -------
    d_um : (N, 3) float
    """
    return Compensator(model, limits_um).linear(p_um, extra=extra)


def optimal_compensator(
    model: KinematicModel,
    p_um: ArrayLike,
    *,
    extra: ArrayLike | None = None,
    limits_um: ArrayLike | None = None,
    tol_um: float = 1e-9,
    max_iter: int = 20,
) -> Compensation:
    """Solve the model for the joints (Eq 4.17-4.19), vectorised over N targets.

    Parameters
    ----------
    model : KinematicModel
        Any model of the term library with joints dx, dy, dz.
    p_um : (N, 3) or (3,) float
        Desired positions in {G}, µm.
    extra : float or (N, e) float, optional
        Values of the model's extra inputs, given (not solved for); left out, each approach
        direction is +1 (a model with other inputs then needs them).
    limits_um : (3, 2) float, optional
        Soft limits per joint; a converged solution outside raises LimitError.
    tol_um : float
        A target has converged when ``|model(d) - p|`` is at most this.
    max_iter : int
        Newton iterations at most before the fallback.

    Returns
    -------
    Compensation

    Notes
    -----
    For repeated calls with the same model, build a :class:`Compensator` once and call its
    ``solve``: the linear part is then checked and factored only once.
    """
    return Compensator(model, limits_um).solve(p_um, extra=extra, tol_um=tol_um, max_iter=max_iter)
