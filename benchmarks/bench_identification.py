"""Identification speed: the 30-term polynomial model with stepwise selection (3 axes x 9
candidate terms + constants) on 170 and on 10 000 poses, time per fit.

Baseline in the same run: the straightforward stepwise search that refits every candidate
model from scratch with ``numpy.linalg.lstsq`` and takes its statistics from
``inv(X^T X)``, one candidate at a time, with the same entry and removal rules.
"""

from __future__ import annotations

import numpy as np
import scipy.stats

from microcal.kinematics import JOINTS, design_matrix, fit_polynomial_model, polynomial_terms
from microcal.sim.synthetic_run import synthetic_run

from .harness import Case, best_time_s


def _pvalue(X: np.ndarray, y: np.ndarray, col: int) -> float:
    A = np.column_stack([np.ones(len(y)), X])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = y - A @ coef
    dof = len(y) - A.shape[1]
    cov = (resid @ resid / dof) * np.linalg.inv(A.T @ A)
    t = coef[col + 1] / np.sqrt(cov[col + 1, col + 1])
    return float(2 * scipy.stats.t.sf(abs(t), dof))


def naive_stepwise(X: np.ndarray, y: np.ndarray, penter=0.05, premove=0.10) -> list[int]:
    inside: list[int] = []
    for _ in range(10 * X.shape[1]):
        out = [j for j in range(X.shape[1]) if j not in inside]
        p_out = [_pvalue(X[:, [*inside, j]], y, len(inside)) for j in out]
        if out and min(p_out) < penter:
            inside.append(out[int(np.argmin(p_out))])
            continue
        p_in = [_pvalue(X[:, inside], y, k) for k in range(len(inside))]
        if p_in and max(p_in) > premove:
            inside.pop(int(np.argmax(p_in)))
            continue
        break
    return inside


def naive_fit(d: np.ndarray, p: np.ndarray) -> None:
    X = design_matrix(d, JOINTS, polynomial_terms())[:, :-1]
    for axis in range(3):
        chosen = naive_stepwise(X, p[:, axis])
        A = np.column_stack([np.ones(len(d)), X[:, chosen]])
        np.linalg.lstsq(A, p[:, axis], rcond=None)


def run() -> list[Case]:
    cases = []
    for n in (170, 10_000):
        data = synthetic_run(n, seed=3)
        d, p = data.d_um, data.measured_um
        repeat = 20 if n == 170 else 3
        t_ours = best_time_s(lambda d=d, p=p: fit_polynomial_model(d, p), repeat)
        t_naive = best_time_s(lambda d=d, p=p: naive_fit(d, p), max(1, repeat // 4))
        cases.append(
            Case(
                name=f"fit 30-term model + stepwise, {n} poses",
                unit="fits/s",
                value=1.0 / t_ours,
                baseline_name="refit every candidate",
                baseline=1.0 / t_naive,
                details={"time_per_fit_s": t_ours, "baseline_time_per_fit_s": t_naive},
            )
        )
    return cases
