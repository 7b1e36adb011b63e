"""Inputs that used to give a wrong number without a word: each is refused in one line, or
warned about while the work goes on.

- stereo calibration by known displacements with views out of order (two images of one
  camera exchanged, or one view's images of the two cameras exchanged);
- a calibration.json whose unselected terms keep coefficients;
- joint commands in millimetres where micrometres are expected;
- negative standard deviations (measurements.csv, cameras.json, calibration.json);
- rows of measurements.csv that repeat another row exactly (a warning: they weight the fit).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from microcal.formats.calibration_file import (
    Calibration,
    ManipulatorCalibration,
    write_calibration,
)
from microcal.formats.measurements import write_measurements
from microcal.kinematics.models import fit_matrix_model
from microcal.sim.camera import ImageFormation, SimCamera
from microcal.sim.clock import SimClock
from microcal.sim.render import Placement
from microcal.sim.synthetic_geometry import look_at_camera
from microcal.sim.synthetic_run import synthetic_run
from microcal.vision.targets import parse_target
from support.hostile import Sandbox, kept_outside, refused_cleanly, run_traced

# --- stereo calibration by known displacements -----------------------------------------------

BOARD = "chessboard:7x4:1000"
STEPS_UM = [(0, 0, 0), (0, 0, 1000), (0, 0, 2000), (0, 0, 3000), (0, 0, 4000), (0, 0, 5000)]


def _views(folder: Path) -> Path:
    """Two small cameras (480 x 360) looking down at a 7 x 4 board stepped along z."""
    board = parse_target(BOARD)
    c = board.centre_um
    models = [look_at_camera(np.array([x, -8000.0, -40000.0]) + c, c, 1200.0, (480, 360), name=n)
              for n, x in (("top", -12000.0), ("side", 12000.0))]  # fmt: skip
    clock, placed = SimClock(), {"p": Placement(board, np.eye(3), np.zeros(3))}
    form = ImageFormation(blur_sigma_px=0.8, defocus_px_per_mm=0.0, read_noise_e=20.0)
    cams = [SimCamera(m, lambda t: [placed["p"]], clock, np.random.default_rng(k), formation=form)
            for k, m in enumerate(models)]  # fmt: skip
    for k, step in enumerate(STEPS_UM):
        placed["p"] = Placement(board, np.eye(3), np.array(step, float))
        for cam in cams:
            cv2.imwrite(str(folder / f"{cam.name}_{k:02d}.png"), cam.grab())
    steps = folder / "steps.csv"
    steps.write_text("dx_um,dy_um,dz_um\n" + "".join(f"{x},{y},{z}\n" for x, y, z in STEPS_UM))
    return steps


def _exchange(a: Path, b: Path) -> None:
    data = a.read_bytes()
    a.write_bytes(b.read_bytes())
    b.write_bytes(data)


def _stereo(box: Sandbox, steps: Path):
    return lambda: run_traced(
        "stereo-calibrate", "--target", BOARD, "--images", f"top={box.case}/top_*.png",
        "--images", f"side={box.case}/side_*.png", "--known-displacements", steps,
        "--out", box.case / "cameras.json",
    )  # fmt: skip


def test_two_views_of_one_camera_exchanged_are_refused_by_name(tmp_path):
    box = Sandbox.make(tmp_path)
    steps = _views(box.case)
    _exchange(box.case / "top_01.png", box.case / "top_03.png")
    line = refused_cleanly(box, _stereo(box, steps), "out of order", "top_01.png", "top_03.png",
                           "--known-displacements")  # fmt: skip
    assert "side_" not in line
    assert not (box.case / "cameras.json").exists()


def test_one_view_exchanged_between_the_cameras_is_refused_by_name(tmp_path):
    box = Sandbox.make(tmp_path)
    steps = _views(box.case)
    _exchange(box.case / "top_02.png", box.case / "side_02.png")
    refused_cleanly(box, _stereo(box, steps), "out of order", "top_02.png", "side_02.png",
                    "--images")  # fmt: skip
    assert not (box.case / "cameras.json").exists()


# --- calibration.json ---------------------------------------------------------------------


def _calibration(box: Sandbox, edit) -> Path:
    """A matrix model of a synthetic run in calibration.json, edited as JSON."""
    run = synthetic_run(30, seed=3)
    model = fit_matrix_model(run.d_um, run.measured_um)
    validation = {"n_fit": 30, "n_validate": 0, "mean_um": 0.5, "std_um": 0.2,
                  "max_um": 1.0, "rms_um": 0.6}  # fmt: skip
    path = write_calibration(box.case / "calibration.json",
                             Calibration({"stage": ManipulatorCalibration("stage", model, validation)}))  # fmt: skip
    doc = json.loads(path.read_text())
    edit(doc["manipulators"]["stage"])
    path.write_text(json.dumps(doc))
    return path


def _solve(path: Path):
    return lambda: run_traced("solve", path, "2000", "2000", "1000")


def test_unselected_terms_that_keep_coefficients_are_refused(tmp_path):
    box = Sandbox.make(tmp_path)

    def unselect_dy_of_y(entry):
        terms = entry["model"]["terms"]
        entry["model"]["selected"][1][terms.index("dy")] = False  # its coefficient stays

    path = _calibration(box, unselect_dy_of_y)
    refused_cleanly(box, _solve(path), str(path), "stage", "dy", "not selected")


def test_a_negative_variance_in_calibration_json_is_refused(tmp_path):
    box = Sandbox.make(tmp_path)

    def negative(entry):
        cov = entry["model"]["covariance"]
        cov[0][1][1] = -abs(cov[0][1][1]) - 1e-6

    path = _calibration(box, negative)
    refused_cleanly(box, _solve(path), str(path), "stage", "covariance", "negative")


def test_a_negative_validation_std_in_calibration_json_is_refused(tmp_path):
    box = Sandbox.make(tmp_path)
    path = _calibration(box, lambda entry: entry["validation"].update(std_um=-0.2))
    refused_cleanly(box, _solve(path), str(path), "stage", "validation.std_um", "negative")


# --- measurements.csv ---------------------------------------------------------------------


def _measurements(box: Sandbox, n: int = 40, *, scale: float = 1.0, std: float | None = None,
                  repeat: int = 0) -> Path:  # fmt: skip
    run = synthetic_run(n, seed=7)
    d, p = run.d_um * scale, run.measured_um
    if repeat:
        d, p = np.vstack([d, d[:repeat]]), np.vstack([p, p[:repeat]])
    sd = None if std is None else np.full((len(d), 3), 0.3)
    if sd is not None:
        sd[4, 1] = std
    return write_measurements(box.case / "measurements.csv", d, p, std_um=sd)


def _fit(box: Sandbox, source: Path, *extra: object):
    return lambda: run_traced("fit", source, "--out", box.case / "calibration.json", *extra)


def test_joint_commands_in_millimetres_are_refused(tmp_path):
    box = Sandbox.make(tmp_path)
    path = _measurements(box, scale=1e-3)
    refused_cleanly(box, _fit(box, path), str(path), "millimetres", "dx_um", "1000")
    assert not (box.case / "calibration.json").exists()


def test_a_negative_standard_deviation_in_measurements_is_refused(tmp_path):
    box = Sandbox.make(tmp_path)
    path = _measurements(box, std=-0.3)
    refused_cleanly(box, _fit(box, path), str(path), "line 6", "sy_um", "below zero")


def test_a_negative_standard_deviation_in_cameras_json_is_refused(tmp_path):
    box = Sandbox.make(tmp_path)
    path = _measurements(box)
    cameras = box.case / "cameras.json"
    top = look_at_camera(np.array([-9000.0, 0, -60000.0]), np.zeros(3), 3000.0, (640, 480))
    side = look_at_camera(np.array([9000.0, 0, -60000.0]), np.zeros(3), 3000.0, (640, 480))
    cams = {
        name: {"model": "pinhole", "image_size_px": [640, 480], "K": m.K.tolist(),
               "dist": [0.0] * 5, "R": m.R.tolist(), "t_um": m.t_um.tolist(),
               "std": {"fx_fy_cx_cy_px": [2.0, 2.0, 0.5, 0.5]}}
        for name, m in (("top", top), ("side", side))
    }  # fmt: skip
    cams["side"]["std"]["fx_fy_cx_cy_px"][2] = -0.5
    cameras.write_text(json.dumps({"format": "microcal.cameras/1", "cameras": cams}))
    refused_cleanly(box, _fit(box, path, "--cameras", cameras), str(cameras),
                    "cameras.side.std.fx_fy_cx_cy_px[2]", "below zero")  # fmt: skip


def test_repeated_rows_are_warned_about_and_fitted(tmp_path):
    box = Sandbox.make(tmp_path)
    path = _measurements(box, repeat=20)
    outcome = kept_outside(box, _fit(box, path))
    ran = outcome.ran
    assert ran.returncode == 0, ran.stderr
    warnings = [line for line in ran.stdout.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1, ran.stdout
    assert "20 rows repeat" in warnings[0], warnings[0]
    assert "weights the fit" in warnings[0], warnings[0]
    assert (box.case / "calibration.json").exists()
