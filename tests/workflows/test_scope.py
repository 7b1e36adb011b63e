"""``microcal scope-calibrate`` and ``scope-show`` on the simulated microscope: two objectives
in one file, each chosen by name; refusals are one line and write nothing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tests.support.cli import invoke_microcal

from microcal.errors import InputError
from microcal.sim.stage_slide import random_truth
from microcal.workflows.scope import ScopeRequest, scope_calibrate, scope_show

ONE_CAMERA = """driver = "hardware"
[manipulator]
kind = "micromanager"
xy_stage = "XY"
focus = "Z"
limits_um = { x = [0, 100], y = [0, 100], z = [0, 100] }
[micromanager]
python_devices = "tests.support.mm_devices:load"
[cameras.scope]
kind = "micromanager"
device = "Camera"
"""


@pytest.mark.slow
def test_two_objectives_in_one_file_each_chosen_by_name(tmp_path):
    out = tmp_path / "scope.json"
    first = scope_calibrate(ScopeRequest("sim", "40x", out, seed=2, image_px=192))
    stored_40x = json.loads(out.read_text())["objectives"]["40x"]
    second = scope_calibrate(ScopeRequest("sim", "10x", out, seed=2, image_px=256,
                                          field_curvature=True))  # fmt: skip
    assert second.frames == 21 + 15
    sag = json.loads(out.read_text())["objectives"]["10x"]["field_curvature"]["corner_um"]
    assert abs(sag - random_truth(2, "10x").field_curvature_um) < 0.5  # 0.9 µm, DOF 6 µm
    assert second.objectives == ["10x", "40x"]
    assert json.loads(out.read_text())["objectives"]["40x"] == stored_40x
    for name, result in (("40x", first), ("10x", second)):
        truth = random_truth(2, name)
        chosen = scope_show(out, name)
        A = np.array(chosen["pixel_size_affine"]).reshape(2, 3)
        np.testing.assert_allclose(A, result.calibration.affine_um)
        scale = np.linalg.norm(A[:, :2], axis=0) / np.linalg.norm(truth.affine_um()[:, :2], axis=0)
        assert np.all(np.abs(scale - 1) < 1e-3), name
    shown = invoke_microcal("scope-show", "--scope", out, "--objective", "10x")
    assert shown.returncode == 0
    assert "Micro-Manager pixel-size affine: " in shown.stdout


def test_an_objective_not_in_the_file_is_one_line(tmp_path):
    out = tmp_path / "scope.json"
    out.write_text(json.dumps({"format": "microcal.scope/1", "objectives": {}}))
    ran = invoke_microcal("scope-show", "--scope", out, "--objective", "40x")
    assert ran.returncode == 2
    assert ran.stderr.strip().splitlines() == [
        f"microcal: error: objective '40x' is not in {out}; it holds none (calibrate it with "
        "microcal scope-calibrate --objective NAME)"
    ]


@pytest.mark.parametrize(
    ("args", "error"),
    [
        (
            ["--rig", "sim", "--objective", "63x"],
            "--objective 63x: the simulated microscope has 10x, 20x, 40x",
        ),
        (
            ["--rig", "RIG", "--objective", "40x"],
            "RIG: cameras: expected two cameras or more (e.g. [cameras.top], [cameras.side]), or "
            "one camera with the microscope's focus device: add [microscope] with focus = "
            '"ZStage" (its Micro-Manager label), xy_stage and limits_um',
        ),
        (
            ["--rig", "sim", "--objective", "40x/oil"],
            "--objective '40x/oil': expected a name of letters, digits and . _ + - (up to 40, e.g. "
            "40x or 10x-air)",
        ),
    ],
)
def test_refusals_are_one_line_and_write_nothing(tmp_path, args, error):
    rig = tmp_path / "one-camera.toml"
    rig.write_text(ONE_CAMERA)
    out = tmp_path / "scope.json"
    args = [str(rig) if a == "RIG" else a for a in args]
    ran = invoke_microcal("scope-calibrate", *args, "--out", out)
    assert ran.returncode == 2
    assert ran.stderr.strip().splitlines() == [f"microcal: error: {error.replace('RIG', str(rig))}"]
    assert not out.exists()


def test_a_rig_without_a_microscope_is_refused(tmp_path):
    examples = Path(__file__).resolve().parents[2] / "examples" / "rigs"
    rig = next(p for p in sorted(examples.glob("*.toml")) if "[cameras." in p.read_text())
    with pytest.raises(InputError, match=r"names no \[microscope\]"):
        scope_calibrate(
            ScopeRequest(str(rig), "40x", tmp_path / "s.json", target="dotgrid:5x5:10:5")
        )


MM_SCOPE = """driver = "hardware"
[micromanager]
python_devices = "support.mm_scope_devices:load"
options = {{ objective = "40x", seed = 5, size = 256 }}
[manipulator]
kind = "micromanager"
xy_stage = "XY"
limits_um = {{ x = [-100, 100], y = [-100, 100] }}
[microscope]
xy_stage = "XY"
focus = "Z"
limits_um = {{ x = [-100, 100], y = [-100, 100], z = [-10, 10] }}
[cameras.scope]
kind = "micromanager"
device = "Scope"
pixel_size_um = {pixel_um}
"""


@pytest.mark.slow
def test_through_micro_manager_devices_the_same_calibration(tmp_path):
    """The hardware path: the rig file's [microscope] moves the slide, the camera grabs."""
    pytest.importorskip("pymmcore_plus", reason="needs pymmcore-plus (pip install 'microcal[mm]')")
    rig = tmp_path / "scope.toml"
    rig.write_text(MM_SCOPE.format(pixel_um=6.5))
    truth = random_truth(5, "40x")
    slide = "dotgrid:41x41:10:5:markers=20,20/22,20/20,19"
    out = tmp_path / "scope.json"
    result = scope_calibrate(ScopeRequest(str(rig), "40x", out, target=slide,
                                          numerical_aperture=0.8))  # fmt: skip
    cal = result.calibration
    A = truth.affine_um()[:, :2]
    assert np.all(np.abs(cal.scale_um / np.linalg.norm(A, axis=0) - 1) < 1e-3)
    assert abs(cal.focus_angle_deg - truth.focus_tilt_deg) < 0.05
    assert scope_show(out, "40x")["camera"] == "scope"
