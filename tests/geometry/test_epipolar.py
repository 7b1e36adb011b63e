"""Epipolar curves: a point's pixel in one view lies on the curve its ray draws in the other."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import sim
from microcal.geometry.epipolar import epipolar_curve_px


@pytest.mark.parametrize("source_name", ["top", "side"])
def test_the_curve_passes_through_the_points_projection(source_name: str):
    models = sim.platform("thesis", seed=3).camera_models
    source = models[source_name]
    other = models["side" if source_name == "top" else "top"]
    rng = np.random.default_rng(5)
    for p in rng.uniform([1000, 1000, 500], [7000, 7000, 4000], (5, 3)):
        q = source.project(p[None, :])[0]
        curve = epipolar_curve_px(source, q, other, near_um=[4000, 4000, 2400], samples=2001)
        assert len(curve) > 100
        # densely sampled: the nearest sample is within the spacing of the samples
        spacing = np.median(np.linalg.norm(np.diff(curve, axis=0), axis=1))
        gap = np.min(np.linalg.norm(curve - other.project(p[None, :])[0], axis=1))
        assert gap <= spacing


def test_a_ray_that_misses_the_other_view_gives_no_curve():
    models = sim.platform("thesis", seed=0).camera_models
    far = [1e7, 1e7, 1e7]
    q = models["top"].project(np.array([[4000.0, 4000.0, 2000.0]]))[0]
    curve = epipolar_curve_px(models["top"], q, models["side"], near_um=far, half_length_um=10.0)
    assert curve.shape == (0, 2)
