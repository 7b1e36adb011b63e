"""`microcal solve`: joint commands from a calibration file."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import load_calibration
from microcal.formats.measurements import write_measurements
from microcal.sim.synthetic_run import synthetic_run
from support.cli import invoke_microcal as microcal


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    d = tmp_path_factory.mktemp("solve")
    run = synthetic_run(170, seed=31)
    write_measurements(d / "measurements.csv", run.d_um, run.measured_um)
    assert microcal("fit", d, "-o", d / "calibration.json").returncode == 0
    return d / "calibration.json"


def test_solve_prints_joints_that_reach_the_target(calibration):
    out = microcal("solve", calibration, 3000, 2500, 1300)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "dx_um dy_um dz_um"
    d = np.array([float(v) for v in lines[1].split()])
    m = load_calibration(calibration).manipulator()
    np.testing.assert_allclose(m.predict_um(d)[0], [3000, 2500, 1300], atol=1e-3)


def test_negative_values_after_double_dash_and_extrapolation_note(calibration):
    out = microcal("solve", calibration, "--", -200, 2000, 300)
    assert out.returncode == 0, out.stderr
    assert "outside the range the model was identified on" in out.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["1", "2"], "position: expected 3 numbers X Y Z in µm, got 2"),
        (["1", "2", "nan"], "position: expected finite numbers"),
        (["3000", "2000", "1300", "--limits", "0:8000,0:8000,0:1000"], "outside the soft limits"),
        (["3000", "2000", "1300", "--limits", "0:8000"], "--limits: expected LOW:HIGH for each joint"),
        (["1", "2", "3", "--manipulator", "m9"], "manipulator 'm9' is not calibrated"),
        (["1", "2", "3", "--temperature", "22"], "--temperature: the model of 'm1' has no temperature input"),
    ],
)  # fmt: skip
def test_user_errors(calibration, args, message):
    out = microcal("solve", calibration, *args)
    assert out.returncode == 2, out.stdout
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert message in lines[0]
    assert out.stdout == ""


def test_missing_or_foreign_calibration(tmp_path):
    out = microcal("solve", tmp_path / "none.json", 1, 2, 3)
    assert out.returncode == 2
    assert "no such file" in out.stderr
    other = tmp_path / "other.json"
    other.write_text('{"format": "microcal.cameras/1"}')
    out = microcal("solve", other, 1, 2, 3)
    assert out.returncode == 2
    assert "expected format 'microcal.calibration/1', got 'microcal.cameras/1'" in out.stderr
