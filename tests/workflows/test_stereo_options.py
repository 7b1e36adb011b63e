"""``stereo-calibrate --lens-model``: the name checked before any image is read, refused with
known displacements, and a fixed model used as asked; ``--out`` never replaces another file."""

from __future__ import annotations

import hashlib
import json

import cv2
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.sim.calibration_views import (
    render_stereo_calibration_views,
    wide_angle_stereo_pair,
)
from microcal.vision.lens_models import LENS_MODELS
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
        ('{"format": "microcal.calibration/1", "cameras": {}}', "holds a 'microcal.calibration/1' file"),
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
