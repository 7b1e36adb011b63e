"""Fast paths of the optimal compensator for polynomial models (powers of the inputs only).

The compensator (:mod:`microcal.kinematics.compensators`) solves ``model(d, e) - p = 0`` by
Newton steps. For a model of monomials with every joint moving, two paths do the same steps
at a fraction of the cost:

- :class:`PlanarNewton`, many targets: the targets are taken in chunks small enough that
  every temporary stays in the processor's cache, each quantity is held as planes (3, n)
  rather than rows (n, 3), one table of powers serves both the residual and the Jacobian at
  a point, and the 3 x 3 systems are solved by Cramer's rule over contiguous planes;
- :class:`ScalarNewton`, one target: the same steps in plain floating point, without the
  fixed cost of array operations on one row.

Either gives up (returns None) on a target that a full step does not improve, and the
compensator's general path (backtracking, then Levenberg-Marquardt) takes it from the
start: the results are those of the general path, to the tolerance.
"""

from __future__ import annotations

import numpy as np

from .._validation import FloatArray

__all__ = ["CHUNK", "PlanarNewton", "ScalarNewton"]

#: Targets per chunk of :class:`PlanarNewton` (a few hundred kB of temporaries).
CHUNK = 4096


class PlanarNewton:
    """Newton steps over many targets at once, as planes (see the module docstring).

    Parameters
    ----------
    exps : (m, k) int
        Exponent of each input in each of the model's m terms (joints first).
    coef : (3, m) float
        The terms' coefficients per output axis.
    R : (3, 3) float
        The coefficients of the joints' linear terms: the start is ``R^-1 (p - offset(e))``,
        the offset being the terms without joints, as the general path's.
    """

    def __init__(self, exps: np.ndarray, coef: FloatArray, R: FloatArray) -> None:
        self.k = exps.shape[1]
        self.max_exp = int(exps.max()) if exps.size else 0
        self.exps = _factors(exps)
        self.coef = coef
        # the start: R^-1 (p - offset(e)), the offset from the terms without joints
        self.R_inv = np.linalg.inv(R)
        free = np.flatnonzero((exps[:, :3] == 0).all(axis=1))
        self.free = (_factors(exps[free]), np.ascontiguousarray(coef[:, free]))
        self.deriv: list[tuple[list[list[tuple[int, int]]], FloatArray]] = []
        for j in range(3):
            used = np.flatnonzero(exps[:, j] > 0)
            lowered = exps[used].copy()
            lowered[:, j] -= 1
            self.deriv.append((_factors(lowered), coef[:, used] * exps[used, j]))

    def _table(self, u: FloatArray) -> FloatArray:
        """Powers 0 .. max_exp of every input, (k, max_exp + 1, n), from u (k, n)."""
        T = np.empty((self.k, self.max_exp + 1, u.shape[1]))
        T[:, 0] = 1.0
        if self.max_exp >= 1:
            T[:, 1] = u
        for e in range(2, self.max_exp + 1):
            np.multiply(T[:, e - 1], u, out=T[:, e])
        return T

    def _eval(
        self, T: FloatArray, factors: list[list[tuple[int, int]]], coef: FloatArray
    ) -> FloatArray:
        """``coef @ terms``, (3, n): each term the product of its factors' rows of T."""
        n = T.shape[2]
        if not factors:
            return np.zeros((3, n))
        terms = np.empty((len(factors), n))
        for row, term in zip(terms, factors, strict=True):
            if not term:
                row.fill(1.0)
                continue
            (i, q), *rest = term
            row[...] = T[i, q]
            for i, q in rest:
                row *= T[i, q]
        out: FloatArray = coef @ terms
        return out

    def solve(
        self, p: FloatArray, e: FloatArray, tol_um: float, max_iter: int
    ) -> tuple[FloatArray, FloatArray, int] | None:
        """Joints (3, n), residual norms (n,) and Newton iterations for targets ``p`` (3, n),
        extra inputs ``e`` (k - 3, n), from the linear part's solution; None if a full step
        fails to lower some target's residual (the general path then solves the chunk)."""
        u = np.zeros((self.k, p.shape[1]))
        u[3:] = e
        offset = self._eval(self._table(u), *self.free)
        u[:3] = self.R_inv @ (p - offset)
        T = self._table(u)
        r = self._eval(T, self.exps, self.coef) - p
        norm = np.sqrt(np.einsum("ij,ij->j", r, r))
        iterations = 0
        while iterations < max_iter and bool((norm > tol_um).any()):
            iterations += 1
            j0, j1, j2 = (self._eval(T, ex, c) for ex, c in self.deriv)
            u[:3] -= _cramer(j0, j1, j2, r)
            T = self._table(u)
            r_trial = self._eval(T, self.exps, self.coef) - p
            n_trial = np.sqrt(np.einsum("ij,ij->j", r_trial, r_trial))
            # every target still off must improve, and none already on may leave the tolerance
            ok = np.where(norm > tol_um, n_trial < norm, n_trial <= tol_um)
            if not bool(ok.all()):
                return None
            r, norm = r_trial, n_trial
        if bool((norm > tol_um).any()):
            return None
        return u[:3].copy(), norm, iterations


def _factors(exps: np.ndarray) -> list[list[tuple[int, int]]]:
    """Each term (a row of exponents, (m, k)) as its (input, power) factors."""
    return [[(i, int(q)) for i, q in enumerate(row) if q > 0] for row in exps.tolist()]


def _cramer(j0: FloatArray, j1: FloatArray, j2: FloatArray, r: FloatArray) -> FloatArray:
    """Solve ``J x = r`` for n 3 x 3 systems given as planes: column b of J is ``jb`` (3, n),
    r (3, n); returns x (3, n)."""
    a, d, g = j0
    b, e, h = j1
    c, f, i = j2
    A = e * i - f * h
    B = f * g - d * i
    C = d * h - e * g
    det = a * A + b * B + c * C
    r0, r1, r2 = r
    x = np.empty_like(r)
    x[0] = A * r0 + (c * h - b * i) * r1 + (b * f - c * e) * r2
    x[1] = B * r0 + (a * i - c * g) * r1 + (c * d - a * f) * r2
    x[2] = C * r0 + (b * g - a * h) * r1 + (a * e - b * d) * r2
    x /= det
    return x


class ScalarNewton:
    """Newton steps for one target in plain floating point (see the module docstring).

    Parameters as :class:`PlanarNewton`.
    """

    def __init__(self, exps: np.ndarray, coef: FloatArray, R: FloatArray) -> None:
        self.k = exps.shape[1]
        self.R_inv = [tuple(row) for row in np.linalg.inv(R).tolist()]
        self.max_exp = int(exps.max()) if exps.size else 0
        # each term as its (input, power) factors, and its coefficient per axis
        self.terms = [[(i, int(q)) for i, q in enumerate(row) if q > 0] for row in exps.tolist()]
        self.coef = [tuple(float(c) for c in col) for col in coef.T.tolist()]
        # the Jacobian's column j: per term with input j, (factor, other factors, coef * q)
        self.deriv = []
        for j in range(3):
            parts = []
            for factors, c in zip(self.terms, self.coef, strict=True):
                for i, q in factors:
                    if i == j:
                        rest = [(ii, qq) for ii, qq in factors if ii != j]
                        if q > 1:
                            rest.append((j, q - 1))
                        parts.append((rest, (c[0] * q, c[1] * q, c[2] * q)))
            self.deriv.append(parts)

    def start(self, p: list[float], e: list[float]) -> list[float]:
        """The linear part's solution ``R^-1 (p - offset(e))``: the terms without joints
        (the constant, the extra inputs' powers) make the offset."""
        P = self._powers([0.0, 0.0, 0.0, *e])
        q = list(p)
        for factors, c in zip(self.terms, self.coef, strict=True):
            if all(i >= 3 for i, _ in factors):
                t = 1.0
                for i, power in factors:
                    t *= P[i][power]
                q = [q[0] - c[0] * t, q[1] - c[1] * t, q[2] - c[2] * t]
        return [sum(a * b for a, b in zip(row, q, strict=True)) for row in self.R_inv]

    def _powers(self, u: list[float]) -> list[list[float]]:
        out = []
        for x in u:
            row = [1.0, x]
            for _ in range(2, self.max_exp + 1):
                row.append(row[-1] * x)
            out.append(row)
        return out

    def _value(self, P: list[list[float]]) -> tuple[float, float, float]:
        x = y = z = 0.0
        for factors, (cx, cy, cz) in zip(self.terms, self.coef, strict=True):
            t = 1.0
            for i, q in factors:
                t *= P[i][q]
            x += cx * t
            y += cy * t
            z += cz * t
        return x, y, z

    def _column(self, P: list[list[float]], j: int) -> tuple[float, float, float]:
        x = y = z = 0.0
        for rest, (cx, cy, cz) in self.deriv[j]:
            t = 1.0
            for i, q in rest:
                t *= P[i][q]
            x += cx * t
            y += cy * t
            z += cz * t
        return x, y, z

    def solve(
        self, p: list[float], e: list[float], d: list[float], tol_um: float, max_iter: int
    ) -> tuple[list[float], float, int] | None:
        """Joints, residual norm and Newton iterations for one target ``p`` with extra
        inputs ``e``, from ``d``; None if a full step does not lower the residual."""
        u = [*d, *e]
        P = self._powers(u)
        m = self._value(P)
        r = (m[0] - p[0], m[1] - p[1], m[2] - p[2])
        norm = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) ** 0.5
        iterations = 0
        while norm > tol_um and iterations < max_iter:
            iterations += 1
            a, dd, g = self._column(P, 0)
            b, ee, h = self._column(P, 1)
            c, f, i = self._column(P, 2)
            A, B, C = ee * i - f * h, f * g - dd * i, dd * h - ee * g
            det = a * A + b * B + c * C
            if det == 0.0:
                return None
            s0 = (A * r[0] + (c * h - b * i) * r[1] + (b * f - c * ee) * r[2]) / det
            s1 = (B * r[0] + (a * i - c * g) * r[1] + (c * dd - a * f) * r[2]) / det
            s2 = (C * r[0] + (b * g - a * h) * r[1] + (a * ee - b * dd) * r[2]) / det
            u[0] -= s0
            u[1] -= s1
            u[2] -= s2
            P = self._powers(u)
            m = self._value(P)
            r = (m[0] - p[0], m[1] - p[1], m[2] - p[2])
            trial = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) ** 0.5
            if not trial < norm:
                return None
            norm = trial
        if norm > tol_um:
            return None
        return u[:3], norm, iterations
