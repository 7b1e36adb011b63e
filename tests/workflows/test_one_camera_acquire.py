"""``microcal acquire`` on the one-camera ``patch`` rig (small frames, few poses): the run
directory, ``fit`` on it against the demo's identification, a stopped run resumed, and the
refusals, in-process."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.errors import FormatError, InputError
from microcal.experiments.patch_demo import identify_run
from microcal.formats.measurements import read_measurements
from microcal.formats.pose_journal import PoseJournal
from microcal.formats.scope_file import write_objective
from microcal.procedures.acquisition import RunStoppedError
from microcal.procedures.one_camera_acquisition import OneCameraRun
from microcal.sim.patch import PatchConfig
from microcal.sim.patch_scope import true_frame
from microcal.workflows.acquire import AcquireRequest
from microcal.workflows.adaptive_acquire import acquire_any
from microcal.workflows.fit import FitRequest, fit
from microcal.workflows.measure import measure_run
from microcal.workflows.one_camera_acquire import _pose_of

SIZE = [512, 512]
VOLUME = "20,20,8"


def _rig(tmp_path: Path, preset: str = "patch") -> Path:
    path = tmp_path / "rig.toml"
    path.write_text(f'driver = "sim"\npreset = "{preset}"\nseed = 2\n[overrides]\n'
                    f"size_px = {SIZE}\nsupersample = 1\n")  # fmt: skip
    return path


def _scope(tmp_path: Path) -> Path:
    """A scope file whose 40x set is the rig's truth (as a perfect scope calibration)."""
    frame = true_frame(PatchConfig())
    affine = np.column_stack([-np.linalg.inv(frame.px_per_um), np.zeros(2)])
    record = {
        "pixel_size_affine": [float(v) for v in affine.ravel()],
        "pixel_size_um": PatchConfig().um_per_px, "rotation_deg": 0.0,
        "distortion": {"model": "radial2", "k": [0.0, 0.0]},
        "focus": {"drift_px_per_um": [float(v) for v in frame.drift_px_per_um]},
    }  # fmt: skip
    path = tmp_path / "scope.json"
    write_objective(path, "40x", record)
    return path


def _request(tmp_path: Path, **changes: object) -> AcquireRequest:
    given: dict[str, object] = {
        "rig": str(_rig(tmp_path)), "scope": _scope(tmp_path), "objective": "40x",
        "poses": 14, "volume_um": VOLUME, "settle": "fixed:0.3",
    }  # fmt: skip
    return AcquireRequest(tmp_path / "run", **{**given, **changes})  # type: ignore[arg-type]


def _journal(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "poses.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_fit_of_the_run_gives_the_demos_identification_on_the_same_poses(tmp_path):
    lines = list(acquire_any(_request(tmp_path, poses=30)))
    run_dir = tmp_path / "run"
    assert lines[-1].startswith(f"stored 30 poses in {run_dir} (30 tips measured")
    assert sorted(p.name for p in run_dir.iterdir()) == [
        "measurements.csv", "one_camera.json", "poses.jsonl", "run.json"
    ]  # fmt: skip
    meas = read_measurements(run_dir / "measurements.csv")
    stored = [_pose_of(line) for line in _journal(run_dir)]
    run = OneCameraRun(np.array([r.commanded_um for r, _ in stored]), [t for _, t in stored],
                       [r for r, _ in stored])  # fmt: skip
    np.testing.assert_allclose(meas.p_um, run.p_um, atol=1e-6)  # {M}, as measured
    cov_csv = np.loadtxt(run_dir / "measurements.csv", delimiter=",", skiprows=1,
                         usecols=range(11, 17))  # fmt: skip
    np.testing.assert_allclose(cov_csv[:, [0, 3, 5]], run.cov_um2[:, [0, 1, 2], [0, 1, 2]],
                               rtol=1e-5)  # fmt: skip
    got = fit(FitRequest(run_dir, out=tmp_path / "calibration.json")).entry.model
    want = identify_run(run, seed=0)[0].model
    assert tuple(got.extra_inputs) == tuple(want.extra_inputs) == ("sx", "sy", "sz")
    assert [t.name for t in got.terms] == [t.name for t in want.terms]
    np.testing.assert_array_equal(got.selected, want.selected)
    np.testing.assert_allclose(got.coefficients, want.coefficients, rtol=1e-5, atol=1e-6)
    # the model describes the manipulator: its approach axis 30 degrees below horizontal
    x_axis = got.coefficients[:, [t.name for t in got.terms].index("dx")]
    assert np.degrees(np.arctan2(-x_axis[2], -x_axis[0])) == pytest.approx(30.0, abs=0.5)


@pytest.mark.slow
def test_a_stopped_run_resumes_after_the_poses_it_stored(tmp_path, monkeypatch):
    append = PoseJournal.append

    def stop_after_six(self: PoseJournal, line: dict) -> None:
        if self.lines == 6:
            raise KeyboardInterrupt  # Ctrl-C while the seventh pose is stored
        append(self, line)

    monkeypatch.setattr(PoseJournal, "append", stop_after_six)
    with pytest.raises(RunStoppedError, match="6 poses stored; resume with: microcal acquire"):
        list(acquire_any(_request(tmp_path)))
    run_dir = tmp_path / "run"
    before = _journal(run_dir)
    assert len(before) == 6
    assert len(read_measurements(run_dir / "measurements.csv").pose) == 6
    monkeypatch.setattr(PoseJournal, "append", append)
    with (run_dir / "poses.jsonl").open("a") as f:
        f.write('{"record": {"pose": 7, "comm')  # torn by the stop
    lines = list(acquire_any(AcquireRequest(run_dir, resume=True)))
    assert lines[0] == f"resuming {run_dir}: 8 of 14 poses to do (one camera)"
    after = _journal(run_dir)
    assert after[:6] == before
    assert [line["record"]["pose"] for line in after] == list(range(1, 15))
    meas = read_measurements(run_dir / "measurements.csv")
    assert meas.pose.tolist() == list(range(1, 15))
    with pytest.raises(InputError, match="--poses 20: this run was begun with 14"):
        list(acquire_any(AcquireRequest(run_dir, resume=True, poses=20)))


def test_without_a_scope_file_a_one_camera_rig_is_refused_in_one_line(tmp_path):
    with pytest.raises(InputError, match=r"give --scope scope.json --objective 40x") as err:
        list(acquire_any(AcquireRequest(tmp_path / "run", rig=str(_rig(tmp_path)))))
    assert "\n" not in str(err.value)
    assert not (tmp_path / "run").exists()


def test_an_objective_the_scope_file_lacks_is_refused_in_one_line(tmp_path):
    with pytest.raises(InputError, match=r"objective '10x' is not in .*scope\.json; it holds 40x"):
        list(acquire_any(_request(tmp_path, objective="10x")))
    with pytest.raises(InputError, match=r"--objective: name the set of .*scope\.json"):
        list(acquire_any(_request(tmp_path, objective=None)))
    assert not (tmp_path / "run").exists()


def test_a_one_camera_rig_without_its_focus_is_refused_in_one_line(tmp_path):
    rig = tmp_path / "scope-rig.toml"
    rig.write_text('driver = "hardware"\n[micromanager]\npython_devices = "x:y"\n'
                   '[manipulator]\nkind = "micromanager"\nxy_stage = "XY"\n'
                   "limits_um = { x = [0, 8000], y = [0, 8000] }\n"
                   '[cameras.scope]\nkind = "micromanager"\ndevice = "Cam"\n'
                   '[microscope]\nxy_stage = "XY"\nlimits_um = { x = [0, 1], y = [0, 1] }\n')  # fmt: skip
    with pytest.raises(FormatError, match=r'add \[microscope\] with focus = "ZStage"') as err:
        list(acquire_any(_request(tmp_path, rig=str(rig))))
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="preset thesis has cameras around the manipulator"):
        list(acquire_any(_request(tmp_path, rig="sim")))


@pytest.mark.parametrize(
    ("changes", "says"),
    [
        ({"settle": "vision"}, "--settle vision: a one-camera run waits a fixed time"),
        ({"design": "sobol"}, "--design: not for a one-camera run"),
        ({"volume_um": "20,0,5"}, "--volume-um: expected three half sizes > 0"),
        ({"poses": 8}, "--poses: a one-camera run needs 12 or more, got 8"),
        ({"scope": None}, "--objective, --volume-um: for a one-camera run only"),
    ],
)
def test_bad_one_camera_options_are_one_line(tmp_path, changes, says):
    with pytest.raises(InputError, match=says) as err:
        list(acquire_any(_request(tmp_path, **changes)))
    assert "\n" not in str(err.value)
    assert not (tmp_path / "run").exists()


def test_measure_on_a_one_camera_run_names_fit(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "one_camera.json").write_text("{}")
    with pytest.raises(InputError, match=f"a one-camera run, .*; fit it: microcal fit {run_dir}"):
        measure_run(run_dir, tmp_path / "scope.json")
    # it has no cameras.json: without --cameras it is told the same, not asked for one
    got = CliRunner().invoke(app, ["measure", str(run_dir)])
    assert got.exit_code == 2
    assert "a one-camera run, measured as it was acquired" in got.stderr
    assert "--cameras" not in got.stderr


def test_a_run_that_stores_no_pose_leaves_no_run_behind(tmp_path, monkeypatch):
    import microcal.procedures.one_camera_acquisition as procedure

    def no_tip(*args: object, **kwargs: object) -> None:
        raise InputError("one-camera acquisition: no tip at the start pose where it was said")

    monkeypatch.setattr(procedure, "acquire_one_camera", no_tip)
    with pytest.raises(InputError, match="no tip at the start pose"):
        list(acquire_any(_request(tmp_path)))
    assert not (tmp_path / "run").exists()
    (tmp_path / "run").mkdir()  # a directory of the user's: kept, empty
    with pytest.raises(InputError, match="no tip at the start pose"):
        list(acquire_any(_request(tmp_path)))
    assert list((tmp_path / "run").iterdir()) == []


def test_the_dry_run_reads_every_device_and_moves_nothing(tmp_path):
    lines = list(acquire_any(_request(tmp_path, dry_run=True)))
    text = "\n".join(lines)
    assert re.search(r"manipulator at x (9999\.9|10000\.0)\d+, y .* µm, still", text)
    assert "microscope: stage x 0.000, y 0.000 µm, focus 0.000 µm" in text
    assert "camera: 512 x 512 px, uint16" in text
    assert "design: 14 poses in 40 x 40 x 16 µm around the tip, within the soft limits" in text
    assert not (tmp_path / "run").exists()  # nothing written


def test_a_dry_run_volume_beyond_the_limits_is_refused_in_one_line(tmp_path):
    with pytest.raises(InputError, match="--volume-um: joint x would go over") as err:
        list(acquire_any(_request(tmp_path, dry_run=True, volume_um="20000,20,8")))
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="--dry-run and --resume: choose one"):
        list(acquire_any(_request(tmp_path, dry_run=True, resume=True, scope=None,
                                  objective=None, volume_um=None)))  # fmt: skip
