"""The affine (telecentric) camera: projection, its Jacobian, estimation and its uncertainty."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microcal import DegenerateDataError, InputError, project_points
from microcal.geometry import AffineCamera
from microcal.geometry.affine_estimation import (
    estimate_affine_matrix,
    projection_std_px,
    refine_affine_camera,
)
from microcal.sim.synthetic_geometry import random_points
from microcal.thesis.cameras import thesis_cameras

CENTRE_UM = np.array([5000.0, 4800.0, 2700.0])


def telecentric(dist=(2e-3, 0.0, 1e-4, -5e-5, 0.0), which: int = 0) -> AffineCamera:
    """The thesis camera's view made parallel: magnification of its pinhole at the centre."""
    cam = thesis_cameras()[which]
    K = cam.K.copy()
    K[:2, :2] /= float(cam.depth_um(CENTRE_UM)[0])
    return AffineCamera(K, np.array(dist), cam.R, cam.t_um, cam.image_size_px, cam.name)


def test_parallel_projection_ignores_depth_along_the_axis(rng):
    cam = telecentric()
    p = random_points(rng, 20)
    moved = p + 3000.0 * cam.axis
    # Metric: worst-case pixel difference; parallel projection has no depth term.
    assert np.abs(cam.project(moved) - cam.project(p)).max() < 1e-9
    assert (cam.depth_um(moved) - cam.depth_um(p)) == pytest.approx(np.full(20, 3000.0))


def test_matrix_form_and_magnification(rng):
    cam = telecentric(dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    assert cam.P[2].tolist() == [0.0, 0.0, 0.0, 1.0]
    p = random_points(rng, 50)
    assert np.abs(cam.project(p) - project_points(cam.P, p)).max() < 1e-9
    step = cam.project(CENTRE_UM + 100.0 * cam.R[0]) - cam.project(CENTRE_UM)
    # A step of 100 µm along the camera's x axis moves the image by 100 mx pixels.
    assert step[0, 0] == pytest.approx(100.0 * cam.K[0, 0], rel=1e-12)


def test_distortion_is_in_units_of_the_half_diagonal():
    cam = telecentric(dist=(1e-3, 0.0, 0.0, 0.0, 0.0))
    w, h = cam.image_size_px
    corner_ideal = cam.K[:2, 2] + np.array([w, h]) / 2.0
    moved = cam.distort_px(corner_ideal) - corner_ideal
    # k1 = 1e-3 moves a point at the half-diagonal outward by 0.1 % of its radius.
    assert np.linalg.norm(moved) == pytest.approx(1e-3 * cam.radius_px, rel=1e-9)


def test_plane_homography_is_the_projection(rng):
    cam = telecentric(dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    t = np.array([4000.0, 3000.0, 2000.0])
    uv = rng.uniform(-2000, 2000, (30, 2))
    H = cam.plane_to_ideal_px(R, t)
    h = np.column_stack([uv, np.ones(30)]) @ H.T
    world = uv @ R[:, :2].T + t
    assert H[2].tolist() == [0.0, 0.0, 1.0]
    assert np.abs(h[:, :2] / h[:, 2:] - cam.project(world)).max() < 1e-9


def test_from_projection_matrix_round_trips():
    cam = telecentric()
    back = AffineCamera.from_projection_matrix(
        cam.P, cam.image_size_px, cam.dist, principal_point_px=cam.K[:2, 2], depth_um=cam.t_um[2]
    )
    # Metric: worst entries; the factorisation is exact up to rounding.
    assert np.abs(back.P - cam.P).max() < 1e-9
    assert np.abs(back.R - cam.R).max() < 1e-12
    assert np.abs(back.t_um - cam.t_um).max() < 1e-6


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"K": np.diag([0.0, 0.05, 1.0])}, r"K: expected magnifications mx > 0"),
        ({"K": np.array([[0.05, 0, 800], [1, 0.05, 600], [0, 0, 1.0]])}, r"upper triangular"),
        ({"R": np.diag([1.0, 1.0, -1.0])}, r"R: expected a rotation"),
        ({"dist": [0.1, 0.2, 0.3]}, r"dist: expected 4, 5, 8, 12 or 14 coefficients"),
        ({"image_size_px": (0, 10)}, r"image_size_px: expected"),
        ({"projection_sigma_px": -1.0}, r"projection_sigma_px: expected a finite value >= 0"),
    ],
)
def test_bad_parameters_are_refused(kwargs, match):
    base = {"K": np.diag([0.05, 0.05, 1.0]), "dist": np.zeros(5), "R": np.eye(3),
            "t_um": np.zeros(3), "image_size_px": (1600, 1200)}  # fmt: skip
    base.update(kwargs)
    with pytest.raises(InputError, match=match):
        AffineCamera(**base)


def test_a_pinhole_matrix_is_not_affine():
    with pytest.raises(InputError, match=r"P: expected an affine matrix"):
        AffineCamera.from_projection_matrix(thesis_cameras()[0].P, (1600, 1200))


def test_linear_estimate_is_exact_without_noise(rng):
    cam = telecentric(dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    p = random_points(rng, 40)
    P = estimate_affine_matrix(p, cam.project(p))
    assert np.abs(P - cam.P).max() < 1e-9 * np.abs(cam.P).max()


def test_linear_estimate_is_the_least_squares_solution(rng):
    cam = telecentric(dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    p = random_points(rng, 300)
    q = cam.project(p) + rng.normal(0, 0.1, (300, 2))
    P = estimate_affine_matrix(p, q)
    # The plain normal-equations solution of q = [p 1] X, without any normalisation.
    A = np.column_stack([p, np.ones(300)])
    X = np.linalg.solve(A.T @ A, A.T @ q)
    # Metric: worst pixel difference of the two solutions' projections.
    assert np.abs(project_points(P, p) - A @ X).max() < 1e-6


def test_linear_estimate_refuses_coplanar_points(rng):
    p = np.column_stack([rng.uniform(0, 9000, (30, 2)), np.full(30, 100.0)])
    with pytest.raises(DegenerateDataError, match=r"points lie in one plane"):
        estimate_affine_matrix(p, rng.uniform(0, 1000, (30, 2)))
    with pytest.raises(DegenerateDataError, match=r"at least 4 points"):
        estimate_affine_matrix(p[:3] + [[0, 0, 0], [0, 0, 1], [0, 0, 2]], np.zeros((3, 2)))


def _fit(cam, p, q, terms=("k1", "p1", "p2")):
    start = AffineCamera.from_projection_matrix(estimate_affine_matrix(p, q), cam.image_size_px)
    return refine_affine_camera(p, q, start, terms)


def test_refinement_recovers_the_camera(rng):
    cam = telecentric()
    p = random_points(rng, 1500)
    q = cam.project(p) + rng.normal(0, 0.05, (1500, 2))
    fit = _fit(cam, p, q)
    # Metric: RMS residual vector (2 axes of 0.05 px), and the projection against the truth.
    assert fit.rms_px == pytest.approx(0.05 * np.sqrt(2), rel=0.05)
    assert np.abs(fit.camera.project(p) - cam.project(p)).max() < 0.03
    assert fit.camera.dist[0] == pytest.approx(cam.dist[0], abs=4 * fit.std["k1"])


def test_refinement_refuses_unknown_terms(rng):
    cam = telecentric()
    p = random_points(rng, 50)
    with pytest.raises(InputError, match=r"dist_terms: expected some of k1, k2"):
        _fit(cam, p, cam.project(p), ("k9",))


def test_parameter_covariance_matches_monte_carlo():
    rng = np.random.default_rng(11)
    cam = telecentric()
    p = random_points(rng, 800)
    truth = cam.project(p)
    draws, reported = [], []
    for _ in range(60):
        fit = _fit(cam, p, truth + rng.normal(0, 0.05, truth.shape))
        # The rotation parameters are a small rotation left of the start's R (which varies
        # from draw to draw): compare the fitted R against the truth's instead.
        rot = Rotation.from_matrix(fit.camera.R @ cam.R.T).as_rotvec()
        draws.append(np.concatenate([rot, fit.params[3:]]))
        reported.append(np.diag(fit.cov))
    draws = np.array(draws)
    # Metric: each parameter's Monte-Carlo variance against the reported one, relative; 60
    # draws give a variance to about +-18 % (1 sigma), so 45 % is 2.5 sigma.
    ratio = draws.var(axis=0, ddof=1) / np.mean(reported, axis=0)
    assert np.all(np.abs(ratio - 1) < 0.45), ratio


def test_projection_std_matches_monte_carlo():
    rng = np.random.default_rng(12)
    cam = telecentric()
    p = random_points(rng, 800)
    probe = random_points(rng, 5)
    truth = cam.project(p)
    proj, std = [], []
    for _ in range(60):
        fit = _fit(cam, p, truth + rng.normal(0, 0.05, truth.shape))
        proj.append(fit.camera.project(probe))
        std.append(projection_std_px(fit, probe))
    proj = np.array(proj)
    mc = np.sqrt(proj.var(axis=0, ddof=1).sum(axis=1) / 2)  # per axis, px
    # Metric: per-point 1-sigma projection error per axis, relative; 60 draws: ~10 % on a std.
    np.testing.assert_allclose(np.mean(std, axis=0), mc, rtol=0.3)


def test_cameras_json_refuses_an_affine_distortion_that_folds(tmp_path):
    from microcal import FormatError
    from microcal.formats.cameras_file import models_from_dict

    cam = telecentric(dist=(-0.6, 0.0, 0.0, 0.0, 0.0))  # folds back at 0.75 half diagonals
    entry = {"model": "affine", "image_size_px": list(cam.image_size_px), "K": cam.K.tolist(),
             "dist": cam.dist.tolist(), "R": cam.R.tolist(), "t_um": cam.t_um.tolist()}  # fmt: skip
    with pytest.raises(FormatError, match=r"cameras.top: its lens distortion folds back"):
        models_from_dict({"format": "microcal.cameras/1", "cameras": {"top": entry}})
    entry["dist"] = [1e-3, 0.0, 1e-4, -1e-4, 0.0]
    got = models_from_dict({"format": "microcal.cameras/1", "cameras": {"top": entry}})
    assert isinstance(got["top"], AffineCamera)
