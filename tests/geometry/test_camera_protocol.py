"""The camera-model protocol: its contract for every kind of camera, and cameras.json's models."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pytest

from microcal import CameraModel, FormatError, InputError, project_points
from microcal.formats import cameras_file
from microcal.formats.cameras_file import cameras_to_dict, load_cameras, write_cameras
from microcal.geometry import (
    AffineCamera,
    CameraModelProtocol,
    check_camera_model,
    triangulate_cameras,
)
from microcal.sim.synthetic_geometry import random_points
from microcal.thesis.cameras import thesis_cameras
from microcal.vision.measurement import PoseMeasurement, _triangulate
from microcal.vision.stereo_calibration import CameraCalibration, StereoCalibration

# The simulator's lens distortion of the thesis cameras (sim/platforms.py), and a strong one.
DIST_TOP = np.array([0.5, 0.0, 1e-3, -1e-3, 0.0])
DIST_SIDE = np.array([0.4, 0.0, -1e-3, 1e-3, 0.0])
DIST_STRONG = np.array([8.0, -40.0, 4e-3, -3e-3, 100.0])


@dataclass(frozen=True, eq=False)
class ParallelCamera:
    """An affine camera (parallel projection, no distortion) written against the protocol only.

    ``q = m R[:2] p + offset_px``; the rows of R are the image's x and y axes and the viewing
    direction in {G}.
    """

    R: np.ndarray
    magnification_px_per_um: float
    offset_px: np.ndarray
    image_size_px: tuple[int, int] = (1600, 1200)
    name: str = "telecentric"
    kind: ClassVar[str] = "affine"

    @property
    def P(self) -> np.ndarray:
        P = np.zeros((3, 4))
        P[:2, :3] = self.magnification_px_per_um * self.R[:2]
        P[:2, 3] = self.offset_px
        P[2, 3] = 1.0
        return P

    def project(self, p_um: Any) -> np.ndarray:
        p = np.atleast_2d(np.asarray(p_um, dtype=np.float64))
        return p @ self.P[:2, :3].T + self.P[:2, 3]

    def project_jacobian(self, p_um: Any) -> np.ndarray:
        n = np.atleast_2d(np.asarray(p_um, dtype=np.float64)).shape[0]
        return np.broadcast_to(self.P[:2, :3], (n, 2, 3)).copy()

    def undistort_px(self, q_px: Any) -> np.ndarray:
        return np.atleast_2d(np.asarray(q_px, dtype=np.float64)).copy()

    def back_project(self, q_px: Any) -> tuple[np.ndarray, np.ndarray]:
        q = self.undistort_px(q_px)
        origin = ((q - self.offset_px) / self.magnification_px_per_um) @ self.R[:2]
        return origin, np.broadcast_to(self.R[2], origin.shape).copy()


def parallel_side_camera() -> ParallelCamera:
    """A telecentric camera looking along the thesis side camera's axis, workspace centred."""
    side = thesis_cameras()[1]
    m = 0.04  # px/µm: the thesis side camera's scale at its working distance
    centre = np.array([4000.0, 4000.0, 2400.0])
    offset = np.array([800.0, 600.0]) - m * side.R[:2] @ centre
    return ParallelCamera(side.R, m, offset)


def affine_of(cam: CameraModel, dist: tuple[float, ...]) -> AffineCamera:
    """microcal's affine camera with a pinhole camera's view and scale at the workspace."""
    K = cam.K.copy()
    K[:2, :2] /= float(cam.depth_um(np.array([4000.0, 4000.0, 2400.0]))[0])
    return AffineCamera(K, np.array(dist), cam.R, cam.t_um, cam.image_size_px, cam.name)


CAMERAS = {
    "thesis top": lambda: thesis_cameras()[0],
    "thesis side": lambda: thesis_cameras()[1],
    "thesis top, distorted": lambda: thesis_cameras(DIST_TOP, DIST_SIDE)[0],
    "thesis side, distorted": lambda: thesis_cameras(DIST_TOP, DIST_SIDE)[1],
    "thesis top, strong distortion": lambda: thesis_cameras(DIST_STRONG)[0],
    "telecentric side": parallel_side_camera,
    "affine top, distorted": lambda: affine_of(thesis_cameras()[0], (2e-3, 0.0, 1e-4, -5e-5, 0.0)),
    "affine side, strong distortion": lambda: affine_of(
        thesis_cameras()[1], (0.05, -0.02, 1e-3, 1e-3, 0.01)
    ),
}


@pytest.fixture(params=list(CAMERAS))
def camera(request: pytest.FixtureRequest) -> CameraModelProtocol:
    return CAMERAS[request.param]()


def test_camera_model_satisfies_the_protocol(thesis_pair):
    for cam in thesis_pair:
        assert isinstance(cam, CameraModelProtocol)
        assert check_camera_model(cam) is cam
        assert cam.kind == "pinhole"
    assert CameraModel.kind == "pinhole"


def test_check_camera_model_names_the_missing_members(thesis_pair):
    with pytest.raises(InputError, match=r"camera1: expected a camera model \(members name, "
                       r"image_size_px, kind, P, .*\), got dict without name, image_size_px, kind, P,"):  # fmt: skip
        check_camera_model({"P": thesis_pair[0].P}, "camera1")
    assert not isinstance(thesis_pair[0].P, CameraModelProtocol)


def test_contract_members_and_shapes(camera, rng):
    assert isinstance(camera, CameraModelProtocol)
    assert isinstance(camera.name, str)
    assert isinstance(camera.kind, str)
    assert len(camera.image_size_px) == 2
    p = random_points(rng, 7)
    assert camera.P.shape == (3, 4)
    assert camera.project(p).shape == (7, 2)
    assert camera.project_jacobian(p).shape == (7, 2, 3)
    assert camera.undistort_px(camera.project(p)).shape == (7, 2)
    origin, direction = camera.back_project(camera.project(p))
    assert origin.shape == direction.shape == (7, 3)
    assert (camera.P[2, :3] == 0).all() == (camera.kind == "affine")


def test_contract_undistorted_pixels_are_those_of_P(camera, rng):
    p = random_points(rng, 500)
    ideal = camera.undistort_px(camera.project(p))
    # Metric: worst-case pixel distance; the undistortion converges to 1e-6 px.
    assert np.abs(ideal - project_points(camera.P, p)).max() <= 1e-6


def test_contract_rays_pass_through_the_projected_points(camera, rng):
    p = random_points(rng, 2000)
    origin, direction = camera.back_project(camera.project(p))
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0, rtol=0, atol=1e-12)
    v = p - origin
    along = np.einsum("ni,ni->n", v, direction)
    off_ray = np.linalg.norm(v - along[:, None] * direction, axis=1)
    # Metric: worst-case distance of the point from its ray, µm, at the thesis geometry.
    assert off_ray.max() < 1e-6
    if camera.kind == "pinhole":  # the ray leaves the centre towards the scene
        assert np.all(along > 0)


def test_contract_jacobian_matches_finite_differences(camera, rng):
    p = random_points(rng, 50)
    jac = camera.project_jacobian(p)
    h = 1.0  # µm: the projection is nearly linear over the 300 mm working distance
    fd = np.empty_like(jac)
    for k in range(3):
        dp = np.zeros(3)
        dp[k] = h
        fd[:, :, k] = (camera.project(p + dp) - camera.project(p - dp)) / (2 * h)
    # Metric: worst-case difference relative to the largest entry, central differences.
    assert np.abs(jac - fd).max() <= 1e-9 * np.abs(jac).max()


def test_pinhole_back_project_of_ideal_pixels(thesis_pair, rng):
    cam = thesis_cameras(DIST_TOP)[0]
    p = random_points(rng, 200)
    o_ideal, d_ideal = cam.back_project(cam.project(p, distort=False), distort=False)
    o_real, d_real = cam.back_project(cam.project(p))
    np.testing.assert_array_equal(o_ideal, np.broadcast_to(cam.centre_um, o_ideal.shape))
    np.testing.assert_array_equal(o_real, o_ideal)
    # Metric: worst-case angle between the rays, rad; both come from the same points.
    assert np.abs(d_ideal - d_real).max() < 1e-12


def test_triangulation_goes_through_the_protocol(rng):
    """A camera that implements only the protocol triangulates and measures like a pinhole."""
    top, parallel = thesis_cameras()[0], parallel_side_camera()
    p = random_points(rng, 300)
    q1, q2 = top.undistort_px(top.project(p)), parallel.undistort_px(parallel.project(p))
    got, cov = triangulate_cameras(top, parallel, q1, q2, 0.1, 0.1)
    # Metric: worst-case error relative to the point's distance from the origin.
    assert np.max(np.linalg.norm(got - p, axis=1) / np.linalg.norm(p, axis=1)) < 1e-9
    assert cov.shape == (300, 3, 3)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    with pytest.raises(InputError, match="camera2: expected a camera model"):
        triangulate_cameras(top, parallel.P, q1, q2, 0.1, 0.1)

    results = []
    for i in range(4):
        m = PoseMeasurement(i + 1, "ok")
        m.vp_px = {"top": q1[i : i + 1], "tele": q2[i : i + 1]}
        m.vp_cov_px2 = {"top": np.eye(2) * 0.01, "tele": np.eye(2) * 0.01}
        results.append(m)
    _triangulate(results, {"top": top, "tele": parallel}, ["top", "tele"])
    measured = np.array([m.p_um for m in results])
    assert np.max(np.linalg.norm(measured - p[:4], axis=1)) < 1e-9 * np.linalg.norm(p[:4]).max()


# --- cameras.json ------------------------------------------------------------------------


def stereo_calibration() -> StereoCalibration:
    cams = {
        c.name: CameraCalibration(c, 0.05, {"v1": 0.05}, 1, residuals_px={"v1": np.zeros((3, 4))})
        for c in thesis_cameras(DIST_TOP, DIST_SIDE)
    }
    return StereoCalibration("known-displacements", cams, 0.06, 123456.0)


def assert_same_models(got: dict[str, CameraModel], want: dict[str, CameraModel]) -> None:
    assert list(got) == list(want)
    for name, cam in want.items():
        g = got[name]
        assert g.name == name
        assert g.kind == cam.kind == "pinhole"
        assert g.image_size_px == cam.image_size_px
        for key in ("K", "dist", "R", "t_um"):
            np.testing.assert_array_equal(getattr(g, key), getattr(cam, key))


def test_cameras_json_writes_the_model_and_round_trips(tmp_path):
    cal = stereo_calibration()
    data = cameras_to_dict(cal, {"software": "test"})
    assert all(cam["model"] == "pinhole" for cam in data["cameras"].values())
    path = write_cameras(tmp_path / "cameras.json", data)
    assert json.loads(path.read_text())["cameras"]["top"]["model"] == "pinhole"
    assert_same_models(load_cameras(path), cal.models())


def test_cameras_json_without_the_model_key_is_pinhole(tmp_path):
    cal = stereo_calibration()
    data = cameras_to_dict(cal, {})
    for cam in data["cameras"].values():
        del cam["model"]  # as microcal.cameras/1 files were written before the key
    assert_same_models(load_cameras(write_cameras(tmp_path / "cameras.json", data)), cal.models())


@pytest.mark.parametrize("value", ["fisheye", 3, None])
def test_cameras_json_refuses_an_unknown_model(tmp_path, value):
    data = cameras_to_dict(stereo_calibration(), {})
    data["cameras"]["side"]["model"] = value
    path = write_cameras(tmp_path / "cameras.json", data)
    with pytest.raises(FormatError) as info:
        load_cameras(path)
    message = str(info.value)
    assert message == (
        f"{path}: cameras.side.model: expected one of 'pinhole', 'affine', got {value!r} "
        "(a camera model this version of microcal does not know)"
    )


def test_cameras_json_round_trips_an_affine_camera(tmp_path):
    cal = stereo_calibration()
    tele = affine_of(thesis_cameras()[1], (2e-3, 0.0, 1e-4, -5e-5, 0.0))
    cal.cameras["side"] = CameraCalibration(tele, 0.05, {}, 5)
    cal.cameras["side"].model_choice = {"chosen": "affine", "reason": "r", "candidates": []}
    path = write_cameras(tmp_path / "cameras.json", cameras_to_dict(cal, {}))
    raw = json.loads(path.read_text())
    assert raw["cameras"]["side"]["model"] == "affine"
    assert raw["cameras"]["side"]["model_choice"]["chosen"] == "affine"
    loaded = load_cameras(path)
    assert isinstance(loaded["side"], AffineCamera)
    assert isinstance(loaded["top"], CameraModel)
    p = random_points(np.random.default_rng(3), 50)
    # Metric: worst-case pixel difference of the projections, JSON keeps every digit.
    assert np.abs(loaded["side"].project(p) - tele.project(p)).max() < 1e-9


def test_cameras_json_errors_name_the_camera_and_key(tmp_path):
    data = cameras_to_dict(stereo_calibration(), {})
    del data["cameras"]["top"]["K"]
    with pytest.raises(FormatError, match=r"cameras\.json: cameras\.top\.K: Field required"):
        load_cameras(write_cameras(tmp_path / "cameras.json", data))
    data = cameras_to_dict(stereo_calibration(), {})
    data["cameras"]["top"]["R"] = np.diag([1.0, 1.0, -1.0]).tolist()
    with pytest.raises(FormatError, match=r"cameras\.top: R: expected a rotation"):
        load_cameras(write_cameras(tmp_path / "cameras.json", data))


def test_a_new_model_kind_is_one_loader_entry(tmp_path, monkeypatch):
    def load_parallel(cam: dict[str, Any], name: str) -> ParallelCamera:
        return ParallelCamera(np.array(cam["R"]), cam["magnification_px_per_um"],
                              np.array(cam["offset_px"]), tuple(cam["image_size_px"]), name)  # fmt: skip

    monkeypatch.setitem(cameras_file.CAMERA_LOADERS, "affine", load_parallel)
    tele = parallel_side_camera()
    data = cameras_to_dict(stereo_calibration(), {})
    data["cameras"]["tele"] = {"model": "affine", "image_size_px": [1600, 1200],
                               "R": tele.R.tolist(), "magnification_px_per_um": 0.04,
                               "offset_px": tele.offset_px.tolist()}  # fmt: skip
    models = load_cameras(write_cameras(tmp_path / "cameras.json", data))
    assert [m.kind for m in models.values()] == ["pinhole", "pinhole", "affine"]
    np.testing.assert_array_equal(models["tele"].P, tele.P)


@pytest.mark.parametrize("n_coef", [8, 12, 14])
def test_cameras_json_keeps_every_opencv_distortion_model(tmp_path, n_coef):
    """A camera calibrated with OpenCV's rational, thin-prism or tilted model keeps them all."""
    dist = np.array([-0.37, 0.24, 5e-4, -5e-4, -0.13, 0.012, -0.008, 0.004,
                     1.2e-3, -8e-4, -1.1e-3, 6e-4, 0.012, -0.009])[:n_coef]  # fmt: skip
    cams = {
        c.name: CameraCalibration(c, 0.05, {"v1": 0.05}, 1, residuals_px={"v1": np.zeros((3, 4))})
        for c in thesis_cameras(dist, DIST_SIDE)
    }
    cal = StereoCalibration("known-displacements", cams, 0.06, 123456.0)
    path = write_cameras(tmp_path / "cameras.json", cameras_to_dict(cal, {}))
    assert len(json.loads(path.read_text())["cameras"]["top"]["dist"]) == n_coef
    models = load_cameras(path)
    assert_same_models(models, cal.models())
    assert models["top"].dist.shape == (n_coef,)
    assert models["side"].dist.shape == (5,)
    p = random_points(np.random.default_rng(n_coef), 100)
    np.testing.assert_array_equal(models["top"].project(p), cal.models()["top"].project(p))


def test_cameras_json_refuses_a_distortion_of_another_length(tmp_path):
    data = cameras_to_dict(stereo_calibration(), {})
    data["cameras"]["top"]["dist"] = [0.1] * 6
    with pytest.raises(
        FormatError, match=r"cameras\.top: dist: expected 4, 5, 8, 12 or 14 coefficients .*, got 6$"
    ):
        load_cameras(write_cameras(tmp_path / "cameras.json", data))
