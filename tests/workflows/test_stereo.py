"""`microcal stereo-calibrate` on files (microscope and photographs), and `microcal measure` with
the cameras it wrote."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import tifffile

from microcal import sim
from microcal.geometry import CameraModel
from microcal.sim.calibration_views import (
    render_stereo_calibration_views,
    wide_angle_camera,
    wide_angle_stereo_pair,
)
from microcal.sim.camera import ImageFormation, SimCamera
from microcal.sim.clock import SimClock
from microcal.sim.render import Placement
from microcal.sim.synthetic_geometry import look_at_camera
from microcal.vision.targets import parse_target
from support.cli import invoke_microcal


def one_line_error(out, message):
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert message in lines[0]


# the module's tests share what a fixture makes once: one worker runs them all
pytestmark = pytest.mark.xdist_group("workflows-stereo")


@pytest.fixture(scope="module")
def microscope_files(tmp_path_factory):
    """Calibration images (multi-page TIFF per view) and a 6-pose run of the thesis preset."""
    root = tmp_path_factory.mktemp("microscope")
    plat = sim.platform("thesis", seed=31)
    grid = parse_target("dotgrid:40x30:250")
    plat.scene.show_board = False
    steps = [0.0, 1000.0, 2000.0, 3000.0, 4000.0]
    (root / "cal").mkdir()
    for k, z in enumerate(steps):
        plat.scene.fixed = Placement(grid, np.eye(3), np.array([0.0, 0.0, z]))
        for n, cam in plat.cameras.items():
            tifffile.imwrite(
                root / "cal" / f"{n}_{k:02d}.tiff", np.stack([cam.grab() for _ in range(8)])
            )
    (root / "cal" / "steps.csv").write_text(
        "dx_um,dy_um,dz_um\n" + "".join(f"0,0,{z}\n" for z in steps)
    )
    plat.scene.fixed = None
    plat.scene.show_board = True
    run = root / "run"
    (run / "images").mkdir(parents=True)
    d = np.array([[1000, 2000, 500], [6000, 1000, 4000], [3000, 7000, 2500], [7000, 7000, 100],
                  [500, 500, 4500], [4000, 4000, 2400]], float)  # fmt: skip
    rows = ["pose,dx_um,dy_um,dz_um"]
    truth = []
    for i, di in enumerate(d, start=1):
        plat.manipulator.move_to_um(di)
        plat.manipulator.wait_until_stopped(plat.clock)
        plat.clock.sleep(5.0)
        truth.append(plat.truth_position_um())
        for n, cam in plat.cameras.items():
            tifffile.imwrite(
                run / "images" / f"{n}_{i:04d}.tiff", np.stack([cam.grab() for _ in range(5)])
            )
        rows.append(f"{i},{di[0]},{di[1]},{di[2]}")
    (run / "commands.csv").write_text("\n".join(rows) + "\n")
    cams = root / "cameras.json"
    out = invoke_microcal("stereo-calibrate", "--target", "dotgrid:40x30:250", "--images", f"top={root}/cal/top_*.tiff",
                          "--images", f"side={root}/cal/side_*.tiff", "--known-displacements", root / "cal/steps.csv",
                          "--out", cams)  # fmt: skip
    assert out.returncode == 0, out.stderr
    return root, np.array(truth)


@pytest.mark.slow
def test_stereo_calibrate_then_measure(microscope_files):
    root, truth = microscope_files
    cams = root / "cameras.json"
    data = json.loads(cams.read_text())
    assert data["format"] == "microcal.cameras/1"
    for name in ("top", "side"):
        c = data["cameras"][name]
        assert set(c) >= {
            "image_size_px",
            "K",
            "dist",
            "R",
            "t_um",
            "rms_px",
            "views_used",
            "views_rejected",
        }
        assert c["rms_px"] <= 0.1
    assert data["stereo"]["baseline_um"] > 0
    out = invoke_microcal("measure", root / "run", "--cameras", cams)
    assert out.returncode == 0, out.stderr
    assert "measured 6 of 6 poses" in out.stdout
    text = (root / "run" / "measurements.csv").read_text().splitlines()
    header = text[0].split(",")
    rows = [dict(zip(header, line.split(","), strict=True)) for line in text[1:]]
    p = np.array([[float(r[k]) for k in ("x_um", "y_um", "z_um")] for r in rows])
    assert np.sqrt(np.mean(np.sum((p - truth) ** 2, axis=1))) < 3.0


@pytest.mark.slow
def test_measure_marks_broken_poses_and_goes_on(microscope_files, tmp_path):
    root, _ = microscope_files
    cams = root / "cameras.json"
    run = tmp_path / "run"
    (run / "images").mkdir(parents=True)
    for f in (root / "run" / "images").iterdir():
        (run / "images" / f.name).write_bytes(f.read_bytes())
    (run / "commands.csv").write_text((root / "run" / "commands.csv").read_text())
    (run / "images" / "top_0002.tiff").write_bytes(b"not an image")
    (run / "images" / "side_0003.tiff").unlink()
    tifffile.imwrite(run / "images" / "top_0004.tiff", np.full((1200, 1600), 80, np.uint8))
    out = invoke_microcal("measure", run, "--cameras", cams)
    assert out.returncode == 0, out.stderr
    assert "measured 3 of 6 poses" in out.stdout
    assert "pose 2 failed: top: " in out.stdout
    assert "cannot be read as an image" in out.stdout
    assert "pose 3 failed: side: no image images/side_0003.tiff" in out.stdout
    assert "pose 4 failed: top: no 4x3 chessboard found" in out.stdout


def photo_pair():
    """Two ordinary cameras 60 mm apart with strong lens distortion, 1280 x 960."""
    dist = np.array([-0.25, 0.08, 0.0, 0.0, 0.0])
    cams = []
    for name, x in (("left", -30_000.0), ("right", 30_000.0)):
        base = look_at_camera(
            np.array([x, 0.0, -600_000.0]), np.zeros(3), 1100.0, (1280, 960), name=name
        )
        cams.append(CameraModel(base.K, dist, base.R, base.t_um, (1280, 960), name))
    return cams


@pytest.mark.slow
def test_ordinary_photographs_any_format(tmp_path):
    board = parse_target("chessboard:9x6:25000")  # a printed board, 25 mm squares
    clock = SimClock()
    rng = np.random.default_rng(5)
    placement = {"p": None}
    formation = ImageFormation(blur_sigma_px=1.0, defocus_px_per_mm=0.0, read_noise_e=40.0)
    cams = [SimCamera(m, lambda t: [placement["p"]], clock, np.random.default_rng(i), formation=formation)
            for i, m in enumerate(photo_pair())]  # fmt: skip
    writers = [
        ("jpg", lambda path, img: cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_GRAY2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])),
        ("png", lambda path, img: cv2.imwrite(str(path), img.astype(np.uint16) * 257)),
        ("tiff", lambda path, img: tifffile.imwrite(path, img)),
    ]  # fmt: skip
    for k in range(12):
        R, _ = cv2.Rodrigues(np.deg2rad(rng.uniform(-30, 30, 3)) * [1, 1, 0.3])
        t = rng.uniform([-40_000, -30_000, -50_000], [40_000, 30_000, 50_000]) - R @ board.centre_um
        placement["p"] = Placement(board, R, t)
        suffix, write = writers[k % 3]
        for cam in cams:
            write(tmp_path / f"{cam.name}_{k:02d}.{suffix}", cam.grab())
    (tmp_path / "left_99.png").write_bytes(b"broken")  # a corrupt file: rejected, not fatal
    (tmp_path / "right_99.png").write_bytes((tmp_path / "right_00.jpg").read_bytes())
    out = invoke_microcal("stereo-calibrate", "--target", "chessboard:9x6:25000", "--images", f"left={tmp_path}/left_*",
                          "--images", f"right={tmp_path}/right_*", "--out", tmp_path / "cams.json")  # fmt: skip
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "cams.json").read_text())
    assert set(data["cameras"]) == {"left", "right"}
    rejected = data["cameras"]["left"]["views_rejected"]
    assert any(r["image"] == "left_99.png" and "cannot be read" in r["reason"] for r in rejected)
    for name in ("left", "right"):
        assert data["cameras"][name]["rms_px"] < 0.3
        k1 = data["cameras"][name]["dist"][0]
        assert k1 == pytest.approx(-0.25, abs=0.05)
    assert data["stereo"]["baseline_um"] == pytest.approx(60_000, rel=0.05)


@pytest.mark.slow
def test_three_cameras_from_tilted_views(tmp_path):
    cams = wide_angle_stereo_pair()
    R, _ = cv2.Rodrigues(np.deg2rad([3.0, -5.0, 0.0]).reshape(3, 1))
    cams["low"] = wide_angle_camera("low", R=R, t_um=-R @ np.array([50_000.0, -40_000.0, 0.0]))
    target = parse_target("chessboard:7x4:25000")
    views = render_stereo_calibration_views(cams, target, 12, seed=47)
    for name, images in views.images.items():
        for k, image in enumerate(images):
            cv2.imwrite(str(tmp_path / f"{name}_{k:02d}.png"), image)
    args = [a for n in cams for a in ("--images", f"{n}={tmp_path}/{n}_*.png")]
    out = invoke_microcal("stereo-calibrate", "--target", "chessboard:7x4:25000", *args,
                          "--out", tmp_path / "cams.json")  # fmt: skip
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "cams.json").read_text())
    assert list(data["cameras"]) == ["left", "right", "low"]
    assert data["stereo"]["baseline_um"] == pytest.approx(120_000, rel=0.005)
    centre = -np.array(data["cameras"]["low"]["R"]).T @ np.array(data["cameras"]["low"]["t_um"])
    left = -np.array(data["cameras"]["left"]["R"]).T @ np.array(data["cameras"]["left"]["t_um"])
    # Metric: the third camera's distance from the first against the true 64 mm, relative.
    assert np.linalg.norm(centre - left) == pytest.approx(np.hypot(50_000, 40_000), rel=0.005)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--target", "chessboard:4x:400", "--images", "a=x", "--images", "b=y"], "expected KIND:COLSxROWS:PITCH_UM"),
        (["--target", "chessboard:4x3:400", "--images", "a=/nonexistent/*.tiff", "--images", "b=y"], "--images a: no file matches"),
        (["--target", "chessboard:4x3:400", "--images", "top"], "--images: expected CAMERA=GLOB"),
        (["--target", "chessboard:4x3:400", "--images", f"a={__file__}", "--known-displacements", __file__], "expected 2 cameras or more"),
        (["--target", "chessboard:4x3:400", "--images", f"a={__file__}"], "none of its images could be read"),
    ],
)  # fmt: skip
def test_stereo_calibrate_user_errors(args, message):
    one_line_error(invoke_microcal("stereo-calibrate", *args), message)


@pytest.fixture(scope="module")
def rendered_pair(tmp_path_factory):
    """Eight views of a 7 x 4 board rendered for a wide-angle stereo pair, as PNG files."""
    root = tmp_path_factory.mktemp("pair")
    target = parse_target("chessboard:7x4:25000")
    views = render_stereo_calibration_views(wide_angle_stereo_pair(), target, 8, seed=8)
    blank = np.full_like(views.images["left"][0], 90)
    for cam, images in views.images.items():
        for v, image in enumerate(images):
            cv2.imwrite(str(root / f"{cam}_{v:02d}.png"), image)
            cv2.imwrite(str(root / f"blank_{cam}_{v:02d}.png"), blank)
    return root


def test_cameras_that_share_no_view_are_refused_with_the_fix_and_nothing_is_written(
    rendered_pair, tmp_path
):
    from microcal.errors import MicrocalError
    from microcal.workflows.stereo import stereo_calibrate_images

    # left sees views 0-3, right views 4-7 (a blank image where a camera missed the board)
    split = tmp_path / "split"
    split.mkdir()
    for v in range(8):
        left = rendered_pair / (f"left_{v:02d}.png" if v < 4 else f"blank_left_{v:02d}.png")
        right = rendered_pair / (f"right_{v:02d}.png" if v >= 4 else f"blank_right_{v:02d}.png")
        (split / f"l_{v:02d}.png").write_bytes(left.read_bytes())
        (split / f"r_{v:02d}.png").write_bytes(right.read_bytes())
    out = tmp_path / "cameras.json"
    with pytest.raises(MicrocalError) as info:
        stereo_calibrate_images("chessboard:7x4:25000",
                                [f"left={split}/l_*.png", f"right={split}/r_*.png"], out)  # fmt: skip
    message = str(info.value)
    assert len(message.splitlines()) == 1
    assert "share no view of the target" in message
    assert "take views that two or more cameras see at once" in message
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["split"]


def test_one_camera_alone_calibrates_through_calibrate_cameras(rendered_pair, tmp_path):
    out = tmp_path / "cameras.json"
    run = invoke_microcal("calibrate-cameras", "--target", "chessboard:7x4:25000", "--images",
                          f"left={rendered_pair}/left_*.png", "--out", out)  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "lens model of left" in run.stdout
    assert "held-out views" in run.stdout
    assert "one camera, RMS" in run.stdout
    assert "baseline" not in run.stdout  # no second camera
    assert "stereo RMS" not in run.stdout
    data = json.loads(out.read_text())
    assert list(data["cameras"]) == ["left"]
    left = data["cameras"]["left"]
    assert left["views_used"] == 8
    assert left["lens_model"]["name"]
    assert left["diagnostics"]["verdict"] is not None
    # Metric: the rendered camera's focal length against the calibrated one, relative.
    assert left["K"][0][0] == pytest.approx(wide_angle_camera().K[0, 0], rel=0.01)
    held = data["stereo"]["consistency"]["held_out"]["cameras"]["left"]
    assert held["held_out_rms_px"] <= 2.0 * held["training_rms_px"]  # 8 views: 6 predict 2
    assert "pitch" not in data["stereo"]["consistency"]  # nothing to triangulate with


def test_a_pair_writes_the_pitch_and_held_out_figures(rendered_pair, tmp_path):
    out = tmp_path / "cameras.json"
    run = invoke_microcal("stereo-calibrate", "--target", "chessboard:7x4:25000",
                          "--images", f"left={rendered_pair}/left_*.png",
                          "--images", f"right={rendered_pair}/right_*.png", "--out", out)  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "target pitch triangulated along x" in run.stdout
    figures = json.loads(out.read_text())["stereo"]["consistency"]
    for axis in ("x", "y"):
        pitch = figures["pitch"][axis]
        assert pitch["nominal_um"] == 25_000.0
        # Metric: the triangulated neighbour distance's mean against the pitch, relative.
        assert abs(pitch["error"]) < 0.002
        assert abs(pitch["worst_cell_error"]) < 0.01
    assert figures["held_out"]["joint"]["ratio"] < 2.5  # 8 views: 6 predict 2
    assert "closure" not in figures  # two cameras: no third to compose through
