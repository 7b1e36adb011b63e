"""A jaw's taper on the thesis's cameras (22 µm pixels, a blur of 1.7 px, lens distortion):
its vertex from the edges, and its tip point in 3D from two cameras' vertices and axes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from microcal.sim import platform
from microcal.sim.tool_render import render_tool_region, tool_roi
from microcal.sim.tools import ToolPlacement
from microcal.vision.tip import detect_tip
from microcal.vision.tip_target import parse_tip
from microcal.vision.tip_vertex import (
    VERTEX_ALONG_MODEL_PX,
    camera_vertex,
    tip_from_vertices,
    vertex_model_cov_um2,
    vertex_to_tip_um,
)
from microcal.vision.tip_wedge import fit_wedge

JAW = parse_tip("tip:jaw:30:40")
BLUR_PX = 1.7  # the thesis cameras' focus blur (sim.platforms' image formation)
LEVEL_DN = 76.0  # the background's mean DN on those cameras (a reflectance of 0.35)


@pytest.fixture(scope="module")
def gripper():
    plat = platform("thesis-gripper", seed=0)
    assert plat.scene.carried is not None
    m, clock = plat.manipulator, plat.clock
    m.move_to_um([3500.0, 4200.0, 2600.0])
    m.wait_until_stopped(clock)
    board = plat.scene.board_placement(clock.now_s())
    return plat.camera_models, plat.scene.carried.at(board)


def _light(camera, jaw: ToolPlacement) -> np.ndarray:
    """The jaw alone over a grey background, blurred, in DN, noise-free (h, w)."""
    w, h = camera.image_size_px
    roi = tool_roi(camera, jaw, 4 * BLUR_PX + 3)
    assert roi is not None
    x0, y0, x1, y1 = roi
    _, opacity = render_tool_region(camera, jaw, roi, supersample=2)
    light = np.full((h, w), LEVEL_DN, dtype=np.float32)
    light[y0:y1, x0:x1] *= 1.0 - opacity
    return cv2.GaussianBlur(light, (0, 0), BLUR_PX)


def _frame(light: np.ndarray, rng: np.random.Generator, noise_dn: float) -> np.ndarray:
    """A frame of 8 bits whose noise is cut at 0, as a camera without a black level gives."""
    noisy = light + rng.standard_normal(light.shape).astype(np.float32) * noise_dn
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def _along(e: np.ndarray, axis: np.ndarray) -> float:
    return float(e @ axis)


def test_the_vertex_is_found_within_two_hundredths_of_a_pixel_without_noise(gripper):
    cameras, jaw = gripper
    for camera in cameras.values():
        light = _light(camera, jaw)
        det = detect_tip(light, JAW)
        assert det.found, det.reason
        fit = fit_wedge(light, camera, det, end_px=3.4)
        assert not isinstance(fit, str), fit
        truth = camera.project(jaw.vertex_um[None], distort=False)[0]
        assert np.linalg.norm(fit.vertex_px - truth) < 0.02  # px, ideal (0.013 on the side camera)
        assert abs(np.degrees(fit.half_angle_rad) - det.half_angle_deg) < 0.5


@pytest.mark.slow
def test_noise_cut_at_zero_moves_the_vertex_no_more_than_noise_kept_and_the_covariance_is_honest(
    gripper,
):
    """Eight frames at the thesis cameras' noise (13 DN on 76, a jaw of 5 DN: a third of its
    noise is cut at 0), each fitted cut and uncut: the same vertex within 0.05 px (a fit
    blind to the cut moved it by half a pixel), the scatter as the covariance says."""
    cameras, jaw = gripper
    camera = cameras["top"]
    light = _light(camera, jaw)
    truth = camera.project(jaw.vertex_um[None], distort=False)[0]
    rng = np.random.default_rng(4)
    det = detect_tip(_frame(light, rng, 12.8), JAW)
    assert det.found, det.reason
    cut, kept, chi2 = [], [], []
    for _ in range(8):
        noise = rng.standard_normal(light.shape).astype(np.float32) * 12.8
        fit = fit_wedge(np.clip(np.rint(light + noise), 0, 255).astype(np.uint8), camera, det,
                        end_px=3.4)  # fmt: skip
        uncut = fit_wedge(light + noise, camera, det, end_px=3.4)
        assert not isinstance(fit, str)
        assert not isinstance(uncut, str)
        e = fit.vertex_px - truth
        cut.append(_along(e, fit.axis))
        kept.append(_along(uncut.vertex_px - truth, fit.axis))
        chi2.append(float(e @ np.linalg.solve(fit.cov[:2, :2], e)))
    assert abs(np.mean(np.array(cut) - kept)) < 0.05  # px along the axis
    assert abs(np.mean(cut)) < 0.2
    assert np.std(cut) < 0.4
    assert 0.3 < np.mean(chi2) / 2 < 3.0


def test_the_tip_point_in_3d_from_two_cameras_is_within_a_quarter_micrometre(gripper):
    cameras, jaw = gripper
    views = {}
    for name, camera in cameras.items():
        got = camera_vertex([_light(camera, jaw)], JAW, camera)
        assert not isinstance(got, str), got
        views[name] = got
    got = tip_from_vertices(views, cameras, JAW)
    assert not isinstance(got, str), got
    tip, cov = got
    assert np.linalg.norm(tip - jaw.tip_um) < 0.25  # µm
    assert cov.shape == (3, 3)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert vertex_to_tip_um(JAW) == pytest.approx(20.0 / np.sin(np.radians(15.0)))


def test_the_vertex_fits_own_error_is_carried_to_3d_at_its_size(gripper):
    """Both cameras' vertices moved by VERTEX_ALONG_MODEL_PX along their axes: the
    triangulated point moves by one sigma of each camera's share, so its chi-square under the
    model covariance (rank 2: one direction per camera) is 2; on these cameras that is some
    0.3-0.5 µm, mostly along the jaw (x)."""
    import dataclasses

    from microcal.geometry import triangulate_views

    cameras, jaw = gripper
    views = {n: camera_vertex([_light(c, jaw)], JAW, c) for n, c in cameras.items()}
    assert all(not isinstance(v, str) for v in views.values())
    C = vertex_model_cov_um2(views, cameras)  # type: ignore[arg-type]
    names = list(cameras)
    cams = [cameras[n] for n in names]

    def point(vs):
        return triangulate_views(cams, [vs[n].vertex_px[None] for n in names],
                                 [vs[n].cov_px2 for n in names])[0][0]  # fmt: skip

    moved = {n: dataclasses.replace(v, vertex_px=v.vertex_px + VERTEX_ALONG_MODEL_PX * v.axis)
             for n, v in views.items()}  # fmt: skip
    shift = point(moved) - point(views)
    assert float(shift @ np.linalg.pinv(C, rcond=1e-9) @ shift) == pytest.approx(2.0, abs=0.05)
    assert np.linalg.matrix_rank(C, tol=1e-9 * np.trace(C)) == 2
    assert 0.2 < np.sqrt(C[0, 0]) < 0.6  # µm along x, where the jaw runs
    assert vertex_model_cov_um2({"top": views["top"]}, cameras).sum() == 0.0  # type: ignore[arg-type]


def test_one_camera_is_not_enough_and_says_so(gripper):
    cameras, jaw = gripper
    camera = cameras["top"]
    view = camera_vertex([_light(camera, jaw)], JAW, camera)
    assert not isinstance(view, str)
    assert "two are needed" in str(tip_from_vertices({"top": view}, cameras, JAW))


def test_a_frame_without_the_tool_is_left_out_and_most_such_frames_fail_the_view(gripper):
    cameras, jaw = gripper
    camera = cameras["top"]
    light = _light(camera, jaw)
    blank = np.full_like(light, LEVEL_DN)
    view = camera_vertex([light, blank], JAW, camera)
    assert not isinstance(view, str), view
    assert view.frames == 1
    why = camera_vertex([blank, blank, light], JAW, camera)
    assert isinstance(why, str)
    assert "no tool" in why
