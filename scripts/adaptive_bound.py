"""How many poses any design can save against the random design, for the adaptive design's
model: the bound behind the adaptive run's 0.6 of the random design's poses.

The model is the ``smooth`` family over the thesis's workspace (the quadratic, cos1-cos8
along each joint, the approach directions and their change along the travel: 40 terms; the
temperature is left out, it is not chosen). Where the run stops, its fit smooths little
(GCV leaves 30-40 of the 40 terms effective, and a fit to noise-free positions keeps all
40: the population's profiles have content in every wave), so the prediction's variance is
nearly the least-squares one, ``sigma^2 x (X^T X)^-1 x^T``. With the same noise on every
pose, a design's error at the test joints (approached from below, as the compensator does)
is then set by ``I(X) = mean_t x_t (X^T X)^-1 x_t^T`` alone. For N poses this prints:

- ``continuous``: ``I* / N``, the least that N poses can reach with the approach directions
  drawn as the acquisition draws them (each of the 8 patterns equally often, apart from the
  positions): the I-optimal design measure over the candidates, found by the multiplicative
  algorithm, its optimality checked by the equivalence theorem (``gap`` 1 = optimal). No
  design of N poses does better (whole poses only do worse: ``exact``).
- ``exact``: a design of N whole poses, each pose's directions drawn by its number, chosen
  greedily and improved by exchange until no pose changes: what a good sequential design
  reaches.
- ``random``: the median ``I`` of the random design (uniform joints, directions drawn) over
  draws, at each N of a grid; ``random poses`` is the N at which it reaches the design's
  ``I`` (interpolated on log I), and ``ratio`` the design's poses over that.

Usage::

    python scripts/adaptive_bound.py                 # signs drawn with seeds 0-2, 200 draws
    python scripts/adaptive_bound.py --signs 5 --draws 400
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from microcal.experiments.adaptive_run import tip_test_joints_um
from microcal.kinematics.adaptive_design import (
    AdaptiveSettings,
    candidate_joints_um,
    joint_inputs,
)
from microcal.kinematics.families import FAMILIES, family_terms
from microcal.kinematics.terms import design_matrix
from microcal.thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM

INPUTS = ("dx", "dy", "dz", "sx", "sy", "sz")
PATTERNS = np.array(list(itertools.product([-1.0, 1.0], repeat=3)))
SIZES = (40, 45, 50, 55, 60, 70, 80)


def rows(terms: tuple, d_um: np.ndarray, signs: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Design rows of joints (N, 3) with approach directions (N, 3), scaled, (N, m)."""
    x: np.ndarray = design_matrix(joint_inputs(d_um, signs, 0.0, INPUTS), INPUTS, terms) / scale
    return x


def continuous_optimum(per_candidate: np.ndarray, A: np.ndarray, iters: int) -> tuple[float, float]:
    """(I*, equivalence gap) of the I-optimal measure over candidates whose information is
    ``per_candidate`` (C, m, m) (the multiplicative algorithm, square-root step)."""
    c, m, _ = per_candidate.shape
    w = np.full(c, 1.0 / c)
    gap = np.inf
    for _ in range(iters):
        M = np.einsum("c,cij->ij", w, per_candidate) + 1e-12 * np.eye(m)
        Mi = np.linalg.inv(M)
        B = Mi @ A @ Mi
        d = np.maximum(np.einsum("cij,ji->c", per_candidate, B), 0.0)
        t = float(np.trace(A @ Mi))
        gap = float(d.max() / t)
        w *= np.sqrt(d / t)
        w /= w.sum()
    M = np.einsum("c,cij->ij", w, per_candidate)
    return float(np.trace(A @ np.linalg.inv(M))), gap


def _gain(X: np.ndarray, S: np.ndarray, A: np.ndarray) -> np.ndarray:
    """(C,) how much adding each row of ``X`` (C, m) lowers ``trace(A S)``, S the inverse
    information of the rows so far (Sherman-Morrison)."""
    out: np.ndarray = np.einsum("ij,jk,ik->i", X, S @ A @ S, X) / (
        1 + np.einsum("ij,jk,ik->i", X, S, X)
    )
    return out


def exact_design(X_by_pose: list[np.ndarray], A: np.ndarray, n: int, passes: int = 10) -> float:
    """``I`` of an n-pose design: greedy under a weak prior, then exchange passes (each
    pose replaced by the candidate that lowers ``I`` most with the others kept)."""
    m = A.shape[0]
    S = np.eye(m) * 1e3
    chosen: list[int] = []
    for i in range(n):
        X = X_by_pose[i]
        g = _gain(X, S, A)
        g[chosen] = -np.inf
        k = int(np.argmax(g))
        chosen.append(k)
        z = S @ X[k]
        S -= np.outer(z, z) / (1 + X[k] @ z)
    for _ in range(passes):
        changed = False
        for i in range(n):
            others = [c for j, c in enumerate(chosen) if j != i]
            R = np.array([X_by_pose[j][c] for j, c in enumerate(chosen) if j != i])
            Mi = np.linalg.inv(R.T @ R + 1e-9 * np.eye(m))
            g = _gain(X_by_pose[i], Mi, A)
            g[others] = -np.inf
            k = int(np.argmax(g))
            if k != chosen[i] and g[k] > g[chosen[i]] * (1 + 1e-9):
                chosen[i], changed = k, True
        if not changed:
            break
    R = np.array([X_by_pose[j][c] for j, c in enumerate(chosen)])
    return float(np.trace(A @ np.linalg.inv(R.T @ R)))


def random_curve(terms: tuple, scale: np.ndarray, A: np.ndarray, draws: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(N grid, median I of the random design at each N)."""
    grid = np.arange(45, 301, 5)
    med = []
    for n in grid:
        vals = []
        for _ in range(draws):
            d = WORKSPACE_MIN_UM + rng.random((n, 3)) * (WORKSPACE_MAX_UM - WORKSPACE_MIN_UM)
            X = rows(terms, d, rng.choice([-1.0, 1.0], size=(n, 3)), scale)
            try:
                vals.append(float(np.trace(A @ np.linalg.inv(X.T @ X))))
            except np.linalg.LinAlgError:
                vals.append(np.inf)
        med.append(float(np.median(vals)))
    return grid, np.array(med)


def random_poses_for(target: float, grid: np.ndarray, med: np.ndarray) -> float:
    """The random design's poses whose median I equals ``target`` (log-interpolated)."""
    logs = np.log(med)
    if target >= med[0]:
        return float(grid[0])
    if target <= med[-1]:
        return float("nan")
    return float(np.interp(-np.log(target), -logs, grid))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--signs", type=int, default=3, help="draws of the poses' directions")
    ap.add_argument("--draws", type=int, default=200, help="random designs per size")
    ap.add_argument("--iters", type=int, default=3000, help="steps of the continuous optimum")
    args = ap.parse_args()
    workspace = np.column_stack([WORKSPACE_MIN_UM, WORKSPACE_MAX_UM])
    terms = family_terms(FAMILIES["smooth"], INPUTS, dict.fromkeys(INPUTS[3:], 1), workspace)
    cand = candidate_joints_um(AdaptiveSettings(until_um=1.0), WORKSPACE_MIN_UM, WORKSPACE_MAX_UM)
    test = tip_test_joints_um(2000)
    raw = design_matrix(joint_inputs(test, np.ones_like(test), 0.0, INPUTS), INPUTS, terms)
    scale = np.sqrt(np.mean(raw**2, axis=0))
    scale[scale == 0] = 1.0
    Xt = raw / scale
    A = Xt.T @ Xt / len(Xt)
    by_pattern = np.stack([rows(terms, cand, np.broadcast_to(p, cand.shape), scale)
                           for p in PATTERNS])  # fmt: skip
    per_candidate = np.einsum("pci,pcj->cij", by_pattern, by_pattern) / len(PATTERNS)
    i_star, gap = continuous_optimum(per_candidate, A, args.iters)
    rng = np.random.default_rng(0)
    grid, med = random_curve(terms, scale, A, args.draws, rng)
    uniform = np.mean(per_candidate[len(cand) - 2048 :], axis=0)  # the Sobol candidates
    i_uniform = float(np.trace(A @ np.linalg.inv(uniform)))
    print(
        f"{len(terms)} terms; I* = {i_star:.2f} (gap {gap:.4f}); uniform joints: "
        f"{i_uniform:.2f} (the best measure's I-efficiency over uniform: "
        f"{i_uniform / i_star:.2f})"
    )
    print("poses | continuous I*/N: random poses, ratio | exact (per direction draw): ratio")
    for n in SIZES:
        nr = random_poses_for(i_star / n, grid, med)
        exact = []
        for s in range(args.signs):
            signs = np.random.default_rng(100 + s).choice([-1.0, 1.0], size=(n, 3))
            X_by_pose = [rows(terms, cand, np.broadcast_to(sg, cand.shape), scale) for sg in signs]
            i_n = exact_design(X_by_pose, A, n)
            exact.append(n / random_poses_for(i_n, grid, med))
        print(
            f"{n:5d} | {nr:6.1f}, {n / nr:.2f} | " + ", ".join(f"{r:.2f}" for r in exact),
            flush=True,
        )


if __name__ == "__main__":
    main()
