"""Cameras that are numbers but not cameras: folding or absurd distortion, one view twice."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from microcal import FormatError, sim
from microcal.formats.cameras_file import load_cameras, write_cameras
from microcal.geometry.camera_checks import MAX_EDGE_STRETCH, distortion_problem, same_view
from microcal.sim.calibration_views import wide_angle_camera


@pytest.fixture(scope="module")
def thesis():
    return sim.platform("thesis", seed=0).camera_models


def test_real_lenses_pass(thesis):
    assert distortion_problem(thesis["top"]) is None
    assert distortion_problem(thesis["side"]) is None
    assert distortion_problem(wide_angle_camera()) is None  # k1 -0.37, k2 0.24, k3 -0.13
    assert same_view(thesis) is None


@pytest.mark.parametrize(
    ("dist", "words"),
    [
        ((-5e4, 0, 0, 0, 0), "folds back inside the image"),
        ((0.5, 0, 0, 0, -1e8), "folds back inside the image"),
        ((5e4, 0, 0, 0, 0), "changes the image edge's distance from the centre"),
    ],
)
def test_absurd_distortion_is_named(thesis, dist, words):
    model = dataclasses.replace(thesis["top"], dist=np.array(dist, dtype=float))
    problem = distortion_problem(model)
    assert problem is not None
    assert words in problem


@pytest.mark.parametrize(("stretch", "refused"), [(2.5, False), (3.5, True)])
def test_the_edge_stretch_bound_is_the_documented_one(thesis, stretch, refused):
    """k1 such that the image's corners lie ``stretch`` times farther out than without it."""
    top = thesis["top"]
    corner = np.linalg.norm(np.linalg.solve(top.K, [0.0, 0.0, 1.0])[:2])
    k1 = (stretch - 1.0) * stretch**2 / corner**2  # r_d = r (1 + k1 r^2), r_d = corner
    model = dataclasses.replace(top, dist=np.array([k1, 0, 0, 0, 0.0]))
    assert MAX_EDGE_STRETCH == 3.0
    assert (distortion_problem(model) is not None) == refused


def _cameras_file(tmp_path, models):
    data = {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in models.items()}}  # fmt: skip
    return write_cameras(tmp_path / "cameras.json", data)


def test_a_cameras_file_with_one_camera_twice_is_refused(tmp_path, thesis):
    path = _cameras_file(tmp_path, {"top": thesis["top"], "side": thesis["top"]})
    with pytest.raises(FormatError, match="cameras top and side see from one centre"):
        load_cameras(path)


def test_a_cameras_file_with_absurd_distortion_is_refused(tmp_path, thesis):
    path = _cameras_file(tmp_path, thesis)
    data = json.loads(path.read_text())
    data["cameras"]["side"]["dist"] = [-4e4, 0, 0, 0, 0]
    path.write_text(json.dumps(data))
    with pytest.raises(FormatError, match=r"cameras\.side: its lens distortion folds back"):
        load_cameras(path)
