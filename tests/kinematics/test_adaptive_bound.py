"""The design bound of ``scripts/adaptive_bound.py``: its optimum on a case known in closed
form, and no design of whole poses below it."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "adaptive_bound.py"


@pytest.fixture(scope="module")
def bound():
    spec = importlib.util.spec_from_file_location("adaptive_bound", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _line(x):
    """Rows (1, x) of a straight line, (N, 2)."""
    return np.column_stack([np.ones_like(x), x])


def test_continuous_optimum_of_a_line(bound):
    # y = a + b x on [-1, 1], error judged uniformly: A = diag(1, 1/3); the I-optimal
    # measure puts half at each end (M = identity), I* = 1 + 1/3
    x = np.linspace(-1.0, 1.0, 41)
    X = _line(x)
    A = np.diag([1.0, 1.0 / 3.0])
    i_star, gap = bound.continuous_optimum(np.einsum("ci,cj->cij", X, X), A, 2000)
    assert i_star == pytest.approx(4.0 / 3.0, rel=1e-3)
    assert gap == pytest.approx(1.0, abs=1e-3)


def test_no_whole_design_beats_the_continuous_optimum(bound):
    rng = np.random.default_rng(3)
    x = rng.uniform(-1.0, 1.0, 300)
    X = np.column_stack([np.ones_like(x), x, x**2, np.cos(np.pi * x), np.cos(2 * np.pi * x)])
    t = np.linspace(-1.0, 1.0, 401)
    T = np.column_stack([np.ones_like(t), t, t**2, np.cos(np.pi * t), np.cos(2 * np.pi * t)])
    A = T.T @ T / len(T)
    i_star, gap = bound.continuous_optimum(np.einsum("ci,cj->cij", X, X), A, 4000)
    assert gap < 1.01
    for n in (6, 10, 20):
        i_n = bound.exact_design([X] * n, A, n)
        assert n * i_n >= i_star * (1 - 1e-6)  # whole poses never beat the measure
        random = X[rng.choice(len(X), n, replace=False)]
        assert i_n <= np.trace(A @ np.linalg.inv(random.T @ random))  # nor lose to chance
    assert 20 * bound.exact_design([X] * 20, A, 20) < 1.2 * i_star  # and near it with many


def test_random_poses_for_interpolates_on_log_scale(bound):
    grid = np.array([50.0, 100.0, 200.0])
    med = np.array([4.0, 1.0, 0.25])
    assert bound.random_poses_for(2.0, grid, med) == pytest.approx(75.0)
    assert bound.random_poses_for(8.0, grid, med) == 50.0
    assert np.isnan(bound.random_poses_for(0.1, grid, med))
