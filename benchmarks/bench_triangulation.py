"""Triangulation throughput: microcal's vectorised linear and optimal methods against the
per-point SVD loop of the thesis's appendix B, on the thesis's cameras, in the same run.

The loop is timed on a subset (it would take minutes on a million points); rates are points
per second, so the ratio does not depend on the subset's size.
"""

from __future__ import annotations

import numpy as np

from microcal import triangulate, triangulate_optimal
from microcal.sim.synthetic_geometry import random_points
from microcal.thesis.cameras import thesis_cameras

from .harness import Case, best_time_s

N_POINTS = 1_000_000
N_LOOP = 20_000


def thesis_appendix_b_loop(P1, P2, x1, x2):
    """The thesis's appendix-B algorithm (one 4x4 SVD per point), with its defects fixed."""
    out = np.zeros((x1.shape[0], 4))
    for i in range(x1.shape[0]):
        A = np.zeros((4, 4))
        A[0, :] = x1[i, 0] * P1[2, :] - P1[0, :]
        A[1, :] = x1[i, 1] * P1[2, :] - P1[1, :]
        A[2, :] = x2[i, 0] * P2[2, :] - P2[0, :]
        A[3, :] = x2[i, 1] * P2[2, :] - P2[1, :]
        _, _, V = np.linalg.svd(A)
        X = V[-1, :]
        out[i] = X / X[-1]
    return out[:, :3]


def run() -> list[Case]:
    rng = np.random.default_rng(7)
    top, side = thesis_cameras()
    P1, P2 = top.P, side.P
    p = random_points(rng, N_POINTS)
    q1 = top.project(p) + rng.normal(0, 0.09, (N_POINTS, 2))
    q2 = side.project(p) + rng.normal(0, 0.05, (N_POINTS, 2))

    t_vec = best_time_s(lambda: triangulate(P1, P2, q1, q2), repeat=5)
    t_opt = best_time_s(lambda: triangulate_optimal(P1, P2, q1, q2), repeat=3)
    t_loop = best_time_s(lambda: thesis_appendix_b_loop(P1, P2, q1[:N_LOOP], q2[:N_LOOP]), 1)
    rate_vec = N_POINTS / t_vec
    rate_opt = N_POINTS / t_opt
    rate_loop = N_LOOP / t_loop
    ratio = rate_vec / rate_loop
    return [
        Case(
            name="triangulate linear, 1e6 pairs",
            unit="points/s",
            value=rate_vec,
            baseline_name="appendix-B loop",
            baseline=rate_loop,
            goal=">= 50x loop and >= 3e6 points/s",
            meets_goal=ratio >= 50 and rate_vec >= 3e6,
            details={"n_points": N_POINTS, "n_loop": N_LOOP, "time_s": t_vec},
        ),
        Case(
            name="triangulate optimal, 1e6 pairs",
            unit="points/s",
            value=rate_opt,
            baseline_name="appendix-B loop",
            baseline=rate_loop,
            details={"n_points": N_POINTS, "time_s": t_opt},
        ),
    ]
