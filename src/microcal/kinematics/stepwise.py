"""Stepwise selection of regression terms with the semantics of MATLAB's ``stepwisefit``.

The thesis selected its polynomial terms in MATLAB's stepwise GUI (thesis 4.3.2). This is
the same procedure, written from its published description:

- the model always has an intercept; it starts from the terms in ``inmodel`` (none by
  default);
- each step makes one move: among the terms outside the model, the one whose coefficient
  would have the smallest p-value if it were added enters, if that p-value is below
  ``penter``; otherwise, among the terms inside, the one with the largest p-value leaves,
  if that p-value is above ``premove``; otherwise the selection stops;
- the p-values are those of the t test of one coefficient (the partial F test of one term,
  F = t²), computed on centred and scaled columns for numerical safety (scaling does not
  change a p-value);
- terms flagged in ``keep`` stay in their initial state (in or out) throughout.

The result gives, for every column, the coefficient, standard error and p-value it has in
the final model, or for a column outside it, the values it would have if it were added.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.linalg
import scipy.stats
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import DegenerateDataError, InputError

__all__ = ["StepwiseResult", "StepwiseStep", "stepwise_fit"]

#: A column whose part independent of the model is below this fraction of its norm is
#: treated as already explained by the model: it cannot enter.
DEPENDENCE_RTOL = 1e-10


@dataclass(frozen=True)
class StepwiseStep:
    """One move of the selection."""

    action: Literal["add", "remove"]
    column: int  # 0-based
    pval: float  # of the term that moved, before the move
    fstat: float
    rmse: float  # of the model after the move
    in_model: tuple[bool, ...]  # after the move


@dataclass(frozen=True)
class StepwiseResult:
    """The final model of :func:`stepwise_fit`. Arrays have one entry per column of X."""

    in_model: np.ndarray  # (p,) bool
    coef: FloatArray
    se: FloatArray
    pval: FloatArray
    intercept: float
    rmse: float
    dof: int
    n_obs: int
    r2: float
    fstat: float  # of the whole model against the constant model
    pval_model: float
    history: tuple[StepwiseStep, ...] = field(default_factory=tuple)

    @property
    def tstat(self) -> FloatArray:
        """t statistics (coef / se)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            out: FloatArray = self.coef / self.se
        return out


@dataclass(frozen=True)
class _State:
    coef: FloatArray  # scaled units
    se: FloatArray
    pval: FloatArray
    fstat: FloatArray
    rss: float
    dof: int


def _state(Xc: FloatArray, yc: FloatArray, inside: np.ndarray) -> _State:
    """Statistics of the model with the columns ``inside`` (plus the intercept)."""
    n, p = Xc.shape
    idx = np.flatnonzero(inside)
    coef = np.full(p, np.nan)
    se = np.full(p, np.nan)
    if idx.size:
        Q, R = scipy.linalg.qr(Xc[:, idx], mode="economic")
        qy = Q.T @ yc
        resid = yc - Q @ qy
        dof = n - 1 - idx.size
        rss = float(resid @ resid)
        s2 = rss / dof if dof > 0 else np.nan
        coef[idx] = scipy.linalg.solve_triangular(R, qy)
        Rinv = scipy.linalg.solve_triangular(R, np.eye(idx.size))
        se[idx] = np.sqrt(s2 * np.sum(Rinv**2, axis=1))
    else:
        Q = np.zeros((n, 0))
        resid = yc
        dof = n - 1
        rss = float(yc @ yc)
    out = np.flatnonzero(~inside)
    if out.size:
        Xo = Xc[:, out]
        Ro = Xo - Q @ (Q.T @ Xo)
        rr = np.sum(Ro**2, axis=0)
        independent = rr > DEPENDENCE_RTOL * np.sum(Xo**2, axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            re = Ro.T @ resid
            b = re / rr
            dof_new = dof - 1
            rss_new = rss - re**2 / rr
            s2_new = rss_new / dof_new if dof_new > 0 else np.full(out.size, np.nan)
            s = np.sqrt(s2_new / rr)
        coef[out] = np.where(independent, b, np.nan)
        se[out] = np.where(independent, s, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = coef / se
    df = np.where(inside, dof, dof - 1)
    pval = np.where(
        np.isfinite(t) & (df > 0), 2.0 * scipy.stats.t.sf(np.abs(t), np.maximum(df, 1)), np.nan
    )
    return _State(coef, se, pval, t**2, rss, dof)


def _mask(value: ArrayLike | None, p: int, name: str) -> np.ndarray:
    if value is None:
        return np.zeros(p, dtype=bool)
    arr = np.asarray(value)
    if arr.dtype == bool:
        if arr.shape != (p,):
            raise InputError(
                f"{name}: expected {p} booleans (one per column), got shape {arr.shape}"
            )
        return arr.copy()
    idx = arr.astype(int).ravel()
    if np.any((idx < 0) | (idx >= p)) or not np.array_equal(idx, arr.ravel()):
        raise InputError(f"{name}: expected column indices in 0..{p - 1}, got {arr.tolist()}")
    mask = np.zeros(p, dtype=bool)
    mask[idx] = True
    return mask


def stepwise_fit(
    X: ArrayLike,
    y: ArrayLike,
    penter: float = 0.05,
    premove: float = 0.10,
    keep: ArrayLike | None = None,
    inmodel: ArrayLike | None = None,
    *,
    max_steps: int | None = None,
) -> StepwiseResult:
    """Select and fit regression terms stepwise (MATLAB ``stepwisefit`` semantics).

    Parameters
    ----------
    X : (N, p) float
        Candidate terms, one per column, without a constant column (the intercept is
        always in the model).
    y : (N,) float
        Response.
    penter : float
        A term enters if its p-value is below this (default 0.05).
    premove : float
        A term leaves if its p-value is above this (default 0.10); must be >= ``penter``.
    keep : (p,) bool or indices, optional
        Terms that stay in their initial state.
    inmodel : (p,) bool or indices, optional
        Terms in the initial model; none by default.
    max_steps : int, optional
        Stop after this many moves; by default ``10 * p + 10`` (never reached in practice).

    Returns
    -------
    StepwiseResult

    Raises
    ------
    InputError
        Wrong shapes, non-finite values, or ``penter > premove``.
    DegenerateDataError
        Fewer than 3 samples, or a constant response.
    """
    X = as_array(X, "X", (None, None))
    n, p = X.shape
    y = as_array(y, "y", (n,))
    if not (0 < penter <= premove < 1):
        raise InputError(
            f"penter, premove: expected 0 < penter <= premove < 1, got {penter} and {premove}"
        )
    if n < 3:
        raise DegenerateDataError(f"stepwise_fit: expected at least 3 samples, got {n}")
    inside = _mask(inmodel, p, "inmodel")
    kept = _mask(keep, p, "keep")
    if n - 1 - int(inside.sum()) < 1:
        raise DegenerateDataError(
            f"stepwise_fit: the initial model has {int(inside.sum())} terms for {n} samples; "
            f"it leaves no residual degrees of freedom"
        )
    xbar = X.mean(axis=0)
    scale = np.sqrt(np.mean((X - xbar) ** 2, axis=0))
    scale[scale == 0] = 1.0  # a constant column is explained by the intercept: never enters
    Xc = (X - xbar) / scale
    ybar = float(y.mean())
    yc = y - ybar
    tss = float(yc @ yc)
    if tss == 0:
        raise DegenerateDataError("stepwise_fit: the response is constant; nothing to explain")

    history: list[StepwiseStep] = []
    limit = 10 * p + 10 if max_steps is None else max_steps
    state = _state(Xc, yc, inside)
    while len(history) < limit:
        candidates = ~inside & ~kept & np.isfinite(state.pval)
        move: tuple[Literal["add", "remove"], int] | None = None
        if candidates.any():
            j = int(np.flatnonzero(candidates)[np.argmin(state.pval[candidates])])
            if state.pval[j] < penter:
                move = ("add", j)
        if move is None:
            removable = inside & ~kept
            if removable.any():
                pv = np.where(np.isnan(state.pval), np.inf, state.pval)
                j = int(np.flatnonzero(removable)[np.argmax(pv[removable])])
                if pv[j] > premove:
                    move = ("remove", j)
        if move is None:
            break
        action, j = move
        pval_j, f_j = float(state.pval[j]), float(state.fstat[j])
        inside[j] = action == "add"
        state = _state(Xc, yc, inside)
        history.append(
            StepwiseStep(
                action,
                j,
                pval_j,
                f_j,
                float(np.sqrt(state.rss / state.dof)),
                tuple(bool(v) for v in inside),
            )
        )

    coef = state.coef / scale
    se = state.se / scale
    k = int(inside.sum())
    rss = state.rss
    r2 = 1.0 - rss / tss
    if k:
        fstat = ((tss - rss) / k) / (rss / state.dof)
        pval_model = float(scipy.stats.f.sf(fstat, k, state.dof))
    else:
        fstat, pval_model = 0.0, 1.0
    intercept = ybar - float(np.sum(coef[inside] * xbar[inside]))
    return StepwiseResult(
        in_model=inside,
        coef=np.asarray(coef, dtype=np.float64),
        se=np.asarray(se, dtype=np.float64),
        pval=np.asarray(state.pval, dtype=np.float64),
        intercept=intercept,
        rmse=float(np.sqrt(rss / state.dof)),
        dof=state.dof,
        n_obs=n,
        r2=float(r2),
        fstat=float(fstat),
        pval_model=pval_model,
        history=tuple(history),
    )
