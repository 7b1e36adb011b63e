"""A pixel and a depth along the camera's axis: the point of {G}, and its covariance."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import sim
from microcal.geometry.focal_plane import point_at_depth_um, point_at_depth_with_cov


@pytest.fixture(scope="module")
def cameras():
    return sim.platform("thesis", seed=0).camera_models


@pytest.mark.parametrize("name", ["top", "side"])
def test_the_point_projects_on_the_pixel_at_the_depth(cameras, name):
    m = cameras[name]
    rng = np.random.default_rng(3)
    for p in rng.uniform([1000, 1000, 500], [7000, 7000, 4500], size=(5, 3)):
        q = m.project(p[None, :])[0]
        depth = float(m.depth_um(p[None, :])[0])
        np.testing.assert_allclose(point_at_depth_um(m, q, depth), p, atol=1e-4)
        moved = point_at_depth_um(m, q, depth + 100.0)
        assert m.depth_um(moved[None, :])[0] == pytest.approx(depth + 100.0, abs=1e-4)
        np.testing.assert_allclose(m.project(moved[None, :])[0], q, atol=1e-6)


def test_the_covariance_holds_the_pixel_across_and_the_depth_along(cameras):
    m = cameras["top"]
    p = np.array([3600.0, 2600.0, 1800.0])
    q = m.project(p[None, :])[0]
    depth = float(m.depth_um(p[None, :])[0])
    _, only_depth = point_at_depth_with_cov(m, q, depth, np.zeros((2, 2)), 4.0)
    axis = m.R[2]
    # a depth of std 2 µm: 2 µm along the ray, nearly the axis at this distance
    assert float(axis @ only_depth @ axis) == pytest.approx(4.0, rel=1e-3)
    _, only_pixel = point_at_depth_with_cov(m, q, depth, 0.25 * np.eye(2), 0.0)
    assert float(axis @ only_pixel @ axis) == pytest.approx(0.0, abs=1e-6)
    # half a pixel across: the scale of the camera at that depth, ~20 µm per pixel here
    across = np.sqrt(np.linalg.eigvalsh(only_pixel)[-2:])
    assert np.all((across > 5.0) & (across < 15.0))


def test_a_depth_behind_the_camera_gives_nan(cameras):
    m = cameras["top"]
    assert np.all(np.isnan(point_at_depth_um(m, [800.0, 600.0], -1000.0)))
    p, cov = point_at_depth_with_cov(m, [800.0, 600.0], -1000.0, np.eye(2), 1.0)
    assert np.all(np.isnan(p))
    assert np.all(np.isnan(cov))
