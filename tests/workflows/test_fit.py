"""`microcal fit`: the identification command, its output and its user errors."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal import load_calibration
from microcal.cli import app
from microcal.formats.measurements import write_measurements
from microcal.sim.synthetic_run import synthetic_run
from support.cli import invoke_microcal

runner = CliRunner()


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    run = synthetic_run(170, seed=21)
    d = tmp_path_factory.mktemp("run")
    T = np.linspace(21.0, 23.0, 170)
    write_measurements(d / "measurements.csv", run.d_um, run.measured_um, temperature_c=T)
    return d


def test_fit_writes_a_calibration_and_prints_the_model(run_dir, tmp_path):
    out = tmp_path / "calibration.json"
    mat = tmp_path / "calibration.mat"
    result = runner.invoke(app, ["fit", str(run_dir), "--out", str(out), "--mat", str(mat)])
    assert result.exit_code == 0, result.output
    assert "dz^2" in result.output
    assert "first 110 fit, last 60 validate" in result.output
    cal = load_calibration(out)
    assert cal.manipulator("m1").model.kind == "polynomial"
    assert cal.manipulator("m1").validation["n_validate"] == 60
    assert mat.exists()


def test_fit_adds_a_second_manipulator_and_keeps_the_first(run_dir, tmp_path):
    out = tmp_path / "calibration.json"
    assert runner.invoke(app, ["fit", str(run_dir), "-o", str(out)]).exit_code == 0
    result = runner.invoke(
        app, ["fit", str(run_dir / "measurements.csv"), "-o", str(out), "--model", "matrix",
              "--manipulator", "m2", "--folds", "5"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    cal = load_calibration(out)
    assert sorted(cal.manipulators) == ["m1", "m2"]
    v = cal.manipulator("m2").validation
    assert v["method"] == "first 110 fit, last 60 validate"
    assert v["cross_validation"]["folds"] == 5
    assert "5-fold cross-validation" in result.output


def test_temperature_terms(run_dir, tmp_path):
    out = tmp_path / "c.json"
    result = runner.invoke(
        app, ["fit", str(run_dir), "-o", str(out), "--temperature", "--select", "all"]
    )
    assert result.exit_code == 0, result.output
    assert "T^2" in [t.name for t in load_calibration(out).manipulator().model.terms]
    # --extra names the same input through the registry; the report recomputes the model's
    # validation errors with the temperature column.
    out2 = tmp_path / "run" / "calibration.json"
    out2.parent.mkdir()
    (out2.parent / "measurements.csv").write_bytes((run_dir / "measurements.csv").read_bytes())
    result = runner.invoke(app, ["fit", str(out2.parent), "-o", str(out2), "--extra", "temperature",
                                 "--select", "all"])  # fmt: skip
    assert result.exit_code == 0, result.output
    from microcal.report import load_run

    errors = load_run(out2.parent).model_errors()
    poly = next(e for e in errors if e.kind == "polynomial")
    assert poly.model.extra_inputs == ("T",)
    v = load_calibration(out2).manipulator().validation
    assert abs(float(poly.errors_um.mean()) - v["mean_um"]) < 1e-6
    result = runner.invoke(app, ["fit", str(out2.parent), "--extra", "humidity"])
    assert result.exit_code == 2
    assert (
        "extra input: expected one of ['approach_x', 'approach_y', 'approach_z', 'temperature'] or ['approach'], got 'humidity'"
        in result.output
    )


def _write(path, rows):
    path.write_text("pose,status,dx_um,dy_um,dz_um,x_um,y_um,z_um\n" + "\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize(
    ("setup", "args", "message"),
    [
        ("none", ["fit", "{tmp}/missing"], "no such file"),
        ("few", ["fit", "{tmp}/few.csv"], "8 measured poses (0 failed); identifying a model needs at least 12"),
        ("still", ["fit", "{tmp}/still.csv", "--select", "all"], "input 'dz' has the same value in every sample"),
        ("good", ["fit", "{run}", "--train", "170"], "train: expected between 1 and 169"),
        ("good", ["fit", "{run}", "--folds", "1"], "Invalid value for '--folds'"),
        ("good", ["fit", "{run}", "--model", "cubic"], "Invalid value for '--model'"),
        ("good", ["fit", "{run}", "--penter", "0.2"], "expected 0 < penter <= premove < 1"),
        ("badcal", ["fit", "{run}", "--out", "{tmp}/bad.json"], "holds a file microcal did not write"),
        ("notemp", ["fit", "{tmp}/few.csv", "--temperature"], "has no 'temperature_c' column"),
    ],
)  # fmt: skip
def test_user_errors_exit_2_with_one_line(run_dir, tmp_path, setup, args, message):
    rng = np.random.default_rng(0)
    if setup in ("few", "notemp"):
        n = 9 if setup == "few" else 15
        _write(tmp_path / "few.csv", [f"{i},ok,{i},{2 * i},{i * i},1,2,{i}" for i in range(1, n)])
    if setup == "still":
        d = rng.uniform(0, 8000, (40, 3))
        _write(
            tmp_path / "still.csv",
            [f"{i + 1},ok,{a},{b},5,{a},{b},5" for i, (a, b, _) in enumerate(d)],
        )
    if setup == "badcal":
        (tmp_path / "bad.json").write_text("{oops")
    argv = [a.format(tmp=tmp_path, run=run_dir) for a in args]
    out = invoke_microcal(*argv, cwd=tmp_path)
    assert out.returncode == 2, out.stderr + out.stdout
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert message in lines[0]
    assert "Traceback" not in out.stderr
    if setup == "badcal":
        assert (tmp_path / "bad.json").read_text() == "{oops"  # nothing overwritten
    assert not (tmp_path / "calibration.json").exists()


def test_fit_embeds_the_cameras(run_dir, tmp_path):
    from microcal.formats.cameras_file import write_cameras

    plat_models = __import__("microcal").sim.platform("thesis", seed=0).camera_models
    cams = {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in plat_models.items()}}  # fmt: skip
    write_cameras(tmp_path / "cameras.json", cams)
    out = tmp_path / "c.json"
    result = runner.invoke(
        app, ["fit", str(run_dir), "-o", str(out), "--cameras", str(tmp_path / "cameras.json")]
    )
    assert result.exit_code == 0, result.output
    assert sorted(load_calibration(out).cameras) == ["side", "top"]
    assert load_calibration(out).manipulator().extra["matrix_model"]["kind"] == "matrix"
    bad = invoke_microcal(
        "fit", run_dir, "-o", tmp_path / "d.json", "--cameras", run_dir / "measurements.csv"
    )
    assert bad.returncode == 2
    assert "not a JSON file" in bad.stderr
    assert not (tmp_path / "d.json").exists()


def _with_outlier(seed: int, shift_um: float = 40.0, row: int = 17):
    run = synthetic_run(120, seed=seed)
    p = run.measured_um.copy()
    p[row, 2] += shift_um  # a pose measured off (a frame of another pose, a mis-detection)
    return run, p


def test_fit_warns_with_the_pose_number_and_excludes_when_asked(tmp_path):
    run, p = _with_outlier(2)
    n = len(p)
    path = write_measurements(tmp_path / "measurements.csv", run.d_um, p,
                              std_um=np.full((n, 3), 0.5), status=["ok"] * n,
                              reason=[""] * n, pose=list(range(1, n + 1)))  # fmt: skip
    out = invoke_microcal("fit", path, "--out", tmp_path / "calibration.json")
    assert out.returncode == 0, out.stderr
    assert "warning: pose 18 is " in out.stdout
    assert "check it (--exclude-outliers leaves such poses out)" in out.stdout
    out = invoke_microcal("fit", path, "--out", tmp_path / "calibration.json", "--exclude-outliers")
    assert out.returncode == 0, out.stderr
    assert "warning: pose 18 is " in out.stdout
    assert "left out of the fit" in out.stdout


@pytest.mark.parametrize("mat", ["calibration.json", "./calibration.json", "alias.mat"])
def test_the_mat_export_may_not_be_the_calibration_under_another_name(run_dir, tmp_path, mat):
    (tmp_path / "alias.mat").symlink_to(tmp_path / "calibration.json")  # a link not yet live
    out = invoke_microcal("fit", run_dir, "--out", "calibration.json", "--mat", mat, cwd=tmp_path)
    assert out.returncode == 2, out.stdout
    assert out.stderr.strip() == (f"microcal: error: --mat {mat.removeprefix('./')}: is --out too; "
                                  "give the .mat file its own name")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alias.mat"]


@pytest.fixture(scope="module")
def run_with_directions(tmp_path_factory):
    """A run whose measurements recorded each pose's approach direction (as acquire does)."""
    from microcal.sim.kinematics import approach_signs

    run = synthetic_run(170, seed=23)
    s = approach_signs(run.d_um)
    extra = {f"approach_{a}": s[:, i] for i, a in enumerate("xyz")}
    p = run.true_um + np.random.default_rng(23).normal(0.0, 0.1, run.true_um.shape)
    d = tmp_path_factory.mktemp("run")
    write_measurements(d / "measurements.csv", run.d_um, p, extra=extra)
    return d


def test_recorded_directions_are_fitted_by_default_and_said(run_with_directions, tmp_path):
    default = invoke_microcal("fit", run_with_directions, "-o", tmp_path / "a.json")
    assert default.returncode == 0, default.stderr
    assert "note: fitting the direction terms sx, sy, sz" in default.stdout
    without = invoke_microcal("fit", run_with_directions, "-o", tmp_path / "b.json",
                              "--no-approach")  # fmt: skip
    assert without.returncode == 0, without.stderr
    assert "direction terms" not in without.stdout
    a = load_calibration(tmp_path / "a.json").manipulator("m1")
    b = load_calibration(tmp_path / "b.json").manipulator("m1")
    assert set(a.model.extra_inputs) == {"sx", "sy", "sz"}
    assert b.model.extra_inputs == ()
    # Metric: validation RMS of the 3D error, µm (0.1 µm noise per axis); the reversal error
    # of the thesis preset is what the direction terms take out.
    assert a.validation["rms_um"] < 0.5 * b.validation["rms_um"], (a.validation, b.validation)


def test_approach_options_that_cannot_be_met_are_one_line(run_dir, run_with_directions, tmp_path):
    missing = invoke_microcal("fit", run_dir, "-o", tmp_path / "a.json", "--approach")
    assert missing.returncode == 2
    assert "has no 'approach_x' column" in missing.stderr
    both = invoke_microcal("fit", run_with_directions, "-o", tmp_path / "b.json",
                           "--no-approach", "--extra", "approach")  # fmt: skip
    assert both.returncode == 2
    assert "--no-approach and --extra approach: choose one" in both.stderr
    assert not (tmp_path / "a.json").exists()
    assert not (tmp_path / "b.json").exists()


@pytest.mark.parametrize("span_um", [10.0, 8000.0])
def test_joints_spanning_what_the_positions_span_fit_without_a_word(tmp_path, span_um):
    """A run of a few µm, or of millimetres in µm, is neither refused nor warned about: only
    positions spanning 100 times the joints are (joints written in millimetres)."""
    rng = np.random.default_rng(2)
    d = rng.uniform(0.0, span_um, (30, 3))
    p = d @ np.array([[1.0, 0.01, 0.0], [0.0, 0.98, 0.02], [0.0, 0.0, 1.01]]) + [50.0, 60.0, 70.0]
    p = p + rng.normal(0.0, 0.05, p.shape)
    write_measurements(tmp_path / "measurements.csv", d, p)
    out = invoke_microcal("fit", tmp_path, "--model", "matrix", "-o", tmp_path / "c.json")
    assert out.returncode == 0, out.stderr
    assert "warning" not in out.stdout + out.stderr
