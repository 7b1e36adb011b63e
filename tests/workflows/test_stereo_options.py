"""``stereo-calibrate --lens-model``: the name checked before any image is read, refused with
known displacements, and a fixed model used as asked (CLI, procedure and lens_models)."""

from __future__ import annotations

import hashlib
import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.errors import InputError
from microcal.procedures.stereo import calibrate_views
from microcal.sim.calibration_views import (
    render_calibration_views,
    render_stereo_calibration_views,
    wide_angle_camera,
    wide_angle_stereo_pair,
)
from microcal.vision.lens_models import LENS_MODELS, choose_lens_model, fit_camera, lens_model
from microcal.vision.targets import parse_target

runner = CliRunner()
TARGET = "chessboard:7x4:25000"
NAMES = [m.name for m in LENS_MODELS]


def one_line_error(result, *fragments):
    """Exit code 2 and a single ``microcal: error:`` line holding every fragment."""
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("microcal: error: "), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def unreadable_pair(tmp_path):
    """Two cameras' image globs whose files exist but cannot be read as images."""
    for cam in ("left", "right"):
        for k in range(4):
            (tmp_path / f"{cam}_{k:02d}.png").write_bytes(b"not a png")
    return ["--images", f"left={tmp_path}/left_*.png", "--images", f"right={tmp_path}/right_*.png"]


def test_the_unreadable_images_alone_fail_on_reading(unreadable_pair, tmp_path):
    """The control for the tests below: without --lens-model these files fail when read."""
    result = runner.invoke(app, ["stereo-calibrate", "--target", TARGET, *unreadable_pair,
                                 "--out", str(tmp_path / "c.json")])  # fmt: skip
    one_line_error(result, "none of its images could be read")


def test_unknown_lens_model_fails_before_any_image_is_read(unreadable_pair, tmp_path):
    out = tmp_path / "c.json"
    result = runner.invoke(app, ["stereo-calibrate", "--target", TARGET, *unreadable_pair,
                                 "--lens-model", "nope", "--out", str(out)])  # fmt: skip
    line = one_line_error(result, "lens model 'nope'", "auto", *NAMES)
    assert "could be read" not in line
    assert not out.exists()


def test_unknown_lens_model_is_named_before_known_displacements_are_refused(
    unreadable_pair, tmp_path
):
    steps = tmp_path / "steps.csv"
    steps.write_text("dx_um,dy_um,dz_um\n" + "0,0,0\n" * 4)
    result = runner.invoke(app, ["stereo-calibrate", "--target", TARGET, *unreadable_pair,
                                 "--lens-model", "radial9", "--known-displacements", str(steps)])  # fmt: skip
    one_line_error(result, "lens model 'radial9'", *NAMES)


def test_lens_model_with_known_displacements_is_refused(unreadable_pair, tmp_path):
    steps = tmp_path / "steps.csv"
    steps.write_text("dx_um,dy_um,dz_um\n" + "".join(f"0,0,{z}\n" for z in (0, 1000, 2000, 3000)))
    out = tmp_path / "c.json"
    result = runner.invoke(app, ["stereo-calibrate", "--target", TARGET, *unreadable_pair,
                                 "--lens-model", "radial1", "--known-displacements", str(steps),
                                 "--out", str(out)])  # fmt: skip
    line = one_line_error(result, "--lens-model", "known-displacement")
    assert "could be read" not in line
    assert not out.exists()


class _Loader:
    """A view loader that records what it was asked for."""

    def __init__(self):
        self.calls = []

    def __call__(self, cam, i):
        self.calls.append((cam, i))
        raise AssertionError("no image should be read")


NAMES_BY_CAMERA = {"left": ["l0.png", "l1.png"], "right": ["r0.png", "r1.png"]}


def test_procedure_checks_the_lens_model_before_loading():
    load = _Loader()
    with pytest.raises(InputError, match="lens model 'nope'"):
        calibrate_views(NAMES_BY_CAMERA, load, parse_target(TARGET), lens_model="nope")
    assert load.calls == []


def test_procedure_refuses_a_lens_model_with_known_displacements_before_loading():
    load = _Loader()
    with pytest.raises(InputError, match="--lens-model"):
        calibrate_views(NAMES_BY_CAMERA, load, parse_target(TARGET),
                        displacements_um=np.zeros((2, 3)), lens_model="radial1")  # fmt: skip
    assert load.calls == []


@pytest.mark.parametrize("name", ["nope", "", "auto", "Radial1", "radial1 ", "radial4"])
def test_lens_model_unknown_name_raises_input_error(name):
    with pytest.raises(InputError) as info:
        lens_model(name)
    message = str(info.value)
    assert repr(name) in message
    for known in NAMES:
        assert known in message


def test_lens_model_finds_each_model_by_name():
    assert NAMES == ["radial1", "radial2", "radial2-tangential", "radial3-tangential",
                     "rational", "thin-prism", "tilted"]  # fmt: skip
    for model in LENS_MODELS:
        assert lens_model(model.name) is model


@pytest.fixture(scope="module")
def mono_views():
    views = render_calibration_views(wide_angle_camera(), parse_target(TARGET), 6, seed=1)
    obj = [views.target.points_um()] * views.n_views
    return obj, views.corners_px, views.camera.image_size_px


@pytest.mark.parametrize("name", ["radial2", "radial3-tangential", "rational"])
def test_choose_lens_model_with_one_model_uses_it_as_asked(mono_views, name):
    obj, img, size = mono_views
    model = lens_model(name)
    choice = choose_lens_model(obj, img, size, models=(model,))
    assert choice.fit.model is model
    assert choice.reason == f"lens model {name} as asked"
    assert choice.candidates == []
    assert choice.fit.dist.shape == (model.n_coefficients,)
    # The same fit as fitting that model directly (OpenCV's threads make the two calls differ
    # in the last digits): K within 1e-6 px, the distortion coefficients within 1e-5
    # (absolute), the RMS reprojection error within 1e-9 px.
    direct = fit_camera(obj, img, size, model)
    np.testing.assert_allclose(choice.fit.K, direct.K, rtol=0, atol=1e-6)
    np.testing.assert_allclose(choice.fit.dist, direct.dist, rtol=0, atol=1e-5)
    assert choice.fit.rms_px == pytest.approx(direct.rms_px, abs=1e-9)
    # Field of view of the fitted pinhole: within 1 deg of the true camera's (about 75 deg
    # diagonal for fx = 525 px on 640 x 480).
    true_fov = np.degrees(2 * np.arctan(np.hypot(320 / 525.0, 240 / 527.0)))
    assert choice.field_of_view_deg == pytest.approx(true_fov, abs=1.0)


def test_radial2_fixes_the_terms_it_leaves_out(mono_views):
    obj, img, size = mono_views
    choice = choose_lens_model(obj, img, size, models=(lens_model("radial2"),))
    k1, k2, p1, p2, k3 = choice.fit.dist
    assert (p1, p2, k3) == (0.0, 0.0, 0.0)  # fixed by the flags: exactly zero
    assert k1 != 0.0
    assert k2 != 0.0


@pytest.fixture(scope="module")
def stereo_images(tmp_path_factory):
    root = tmp_path_factory.mktemp("stereo")
    views = render_stereo_calibration_views(wide_angle_stereo_pair(), parse_target(TARGET), 8,
                                            seed=1)  # fmt: skip
    for cam, images in views.images.items():
        for k, image in enumerate(images):
            assert cv2.imwrite(str(root / f"{cam}_{k:02d}.png"), image)
    return root


def test_stereo_calibrate_with_a_fixed_lens_model(stereo_images, tmp_path):
    out = tmp_path / "cameras.json"
    result = runner.invoke(app, ["stereo-calibrate", "--target", TARGET,
                                 "--images", f"left={stereo_images}/left_*.png",
                                 "--images", f"right={stereo_images}/right_*.png",
                                 "--lens-model", "radial3-tangential", "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert set(data["cameras"]) == {"left", "right"}
    for name, cam in data["cameras"].items():
        lm = cam["lens_model"]
        assert lm["name"] == "radial3-tangential", name
        assert lm["terms"] == ["k1", "k2", "k3", "p1", "p2"]
        assert lm["candidates"] == []  # one model asked for: no comparison made
        assert len(cam["dist"]) == 5
        # Rendered views with sub-pixel corners: RMS reprojection error below 0.1 px.
        assert cam["rms_px"] < 0.1, name
    # The rig's baseline is 120 mm: within 2 % (relative).
    assert data["stereo"]["baseline_um"] == pytest.approx(120_000, rel=0.02)


@pytest.mark.parametrize(
    ("existing", "message"),
    [
        ('{"format": "microcal.calibration/1", "cameras": {}}', "holds a microcal.calibration/1 file"),
        ("x,y\n1,2\n", "holds a file microcal did not write"),
    ],
)  # fmt: skip
def test_stereo_calibrate_never_replaces_a_file_of_another_kind(tmp_path, existing, message):
    out = tmp_path / "calibration.json"
    out.write_text(existing)
    before = hashlib.sha256(out.read_bytes()).hexdigest()
    result = CliRunner().invoke(
        app, ["stereo-calibrate", "--target", "chessboard:7x4:25000", "--images", "a=x*.png",
              "--images", "b=y*.png", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.startswith("microcal: error:")]
    assert len(lines) == 1, result.output
    assert message in lines[0]
    assert "Traceback" not in result.output
    assert hashlib.sha256(out.read_bytes()).hexdigest() == before


def test_stereo_calibrate_refuses_a_directory_as_out(tmp_path):
    result = CliRunner().invoke(
        app, ["stereo-calibrate", "--target", "chessboard:7x4:25000", "--images", "a=x*.png",
              "--images", "b=y*.png", "--out", str(tmp_path)],
    )  # fmt: skip
    assert result.exit_code == 2
    assert "is a directory; give a file name such as cameras.json" in result.output


@pytest.mark.parametrize("mistake", ["steps in mm", "steps out of order"])
def test_known_displacements_that_fit_no_camera_are_a_clear_error(mistake):
    from microcal.errors import DegenerateDataError
    from microcal.thesis.cameras import thesis_cameras
    from microcal.vision.detect import Detection
    from microcal.vision.stereo_calibration import calibrate_known_displacements

    cams = dict(zip(("top", "side"), thesis_cameras(), strict=True))
    target = parse_target("dotgrid:20x15:250")
    steps = np.array([[0.0, 0.0, z] for z in (0.0, 1000.0, 2000.0, 3000.0, 4000.0)])
    rng = np.random.default_rng(5)
    dets = {
        n: [Detection(True, np.arange(300), c.project(target.points_um() + [2000, 2000, 0] + s)
                      + rng.normal(0, 0.05, (300, 2)), 0.05) for s in steps]
        for n, c in cams.items()
    }  # fmt: skip
    names = {n: [f"{n}{k}" for k in range(5)] for n in cams}
    sizes = {n: c.image_size_px for n, c in cams.items()}
    given = steps / 1000.0 if mistake == "steps in mm" else steps[[3, 0, 4, 1, 2]]
    with pytest.raises(DegenerateDataError, match=r"the views do not fit one camera .*steps in µm"):
        calibrate_known_displacements(dets, names, target, given, sizes)
    # The same detections with the right steps calibrate (metric: RMS reprojection, px).
    cal = calibrate_known_displacements(dets, names, target, steps, sizes)
    assert all(c.rms_px < 0.1 for c in cal.cameras.values())
