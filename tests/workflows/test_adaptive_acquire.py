"""``microcal acquire --design adaptive``: batches acquired, measured and chosen in turn;
a run stopped between batches or within one resumes without losing a pose, and chooses the
poses the run would have chosen without the stop."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.formats.calibration_file import load_calibration
from microcal.formats.measurements import read_measurements
from microcal.formats.run_directory import RunDirectory, RunWriter
from microcal.kinematics.adaptive_design import AdaptiveSettings, workspace_grid_um
from microcal.workflows import adaptive_acquire, adaptive_fit
from microcal.workflows.acquire import AcquireRequest
from microcal.workflows.adaptive_acquire import acquire_any
from microcal.workflows.fit import FitRequest, fit
from support.runs import write_true_cameras

pytestmark = pytest.mark.slow


class StopError(Exception):
    pass


def _request(out: Path, cameras: Path, resume: bool = False) -> AcquireRequest:
    if resume:
        return AcquireRequest(out, resume=True)
    return AcquireRequest(out, rig="sim", design="adaptive", settle="fixed:0", frames=2,
                          until_um=0.01, max_poses=30, cameras=str(cameras))  # fmt: skip


def _run(request: AcquireRequest) -> list[str]:
    return list(acquire_any(request))


def test_adaptive_runs_resume_after_a_stop_between_and_within_batches(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cameras = write_true_cameras(tmp_path / "cameras.json")
    # a stop within the first batch, after its 5th pose is stored
    store = RunWriter.store
    count = {"n": 0}

    def stopping_store(self: RunWriter, pose: int, *args: object, **kwargs: object) -> None:
        if count["n"] == 5:
            raise StopError("the computer went down")
        count["n"] += 1
        store(self, pose, *args, **kwargs)  # type: ignore[arg-type]

    crashed = tmp_path / "crashed"
    monkeypatch.setattr(RunWriter, "store", stopping_store)
    with pytest.raises(StopError):
        _run(_request(crashed, cameras))
    monkeypatch.setattr(RunWriter, "store", store)
    first = RunDirectory.open(crashed / "batch-001")
    kept = {p: line.images for p, line in first.journal().items()}
    assert sorted(kept) == [1, 2, 3, 4, 5]
    # resumed, then stopped again after the first batch was measured, before the second
    step = adaptive_acquire.BatchedDesign.step
    monkeypatch.setattr(adaptive_acquire.BatchedDesign, "step",
                        lambda self, measured: (_ for _ in ()).throw(StopError("again")))  # fmt: skip
    with pytest.raises(StopError):
        _run(_request(crashed, cameras, resume=True))
    monkeypatch.setattr(adaptive_acquire.BatchedDesign, "step", step)
    journal = RunDirectory.open(crashed / "batch-001").journal()
    assert sorted(journal) == list(range(1, 21))
    assert all(journal[p].images == kept[p] for p in kept)  # nothing stored before was lost
    assert (crashed / "batch-001" / "measurements.csv").is_file()
    assert not (crashed / "batch-002").exists()
    lines = _run(_request(crashed, cameras, resume=True))
    assert "30 poses in 3 batches" in lines[-1]
    assert len(RunDirectory.open(crashed / "batch-002").commands()[0]) == 5
    options = json.loads((crashed / "adaptive.json").read_text(encoding="utf-8"))
    assert options["until_um"] == 0.01
    # the run ends read whole: every pose in one measurements.csv, numbered through the run
    merged = read_measurements(crashed / "measurements.csv")
    assert merged.pose.tolist() == list(range(1, 31))
    second = read_measurements(crashed / "batch-002" / "measurements.csv")
    np.testing.assert_array_equal(merged.p_um[20:25], second.p_um)
    assert (crashed / "calibration.json").is_file()
    # a stop after the measurements were merged, before calibration.json: resumed, written
    (crashed / "calibration.json").unlink()
    lines = _run(_request(crashed, cameras, resume=True))
    assert "30 poses in 3 batches" in lines[-1]
    assert load_calibration(crashed / "calibration.json").manipulators["m1"].model.selection[
        "family"] == "smooth"  # fmt: skip


def test_the_same_measurements_choose_the_same_batch_and_the_calibration_is_the_last_fit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cameras = write_true_cameras(tmp_path / "cameras.json")
    steps = []
    step = adaptive_acquire.BatchedDesign.step

    def keeping(self: adaptive_acquire.BatchedDesign, measured: object) -> object:
        steps.append(step(self, measured))  # type: ignore[arg-type]
        return steps[-1]

    monkeypatch.setattr(adaptive_acquire.BatchedDesign, "step", keeping)
    a, b = tmp_path / "a", tmp_path / "b"
    _run(_request(a, cameras))
    last = steps[-1].model
    b.mkdir()
    shutil.copytree(a / "batch-001", b / "batch-001")
    shutil.copy(a / "adaptive.json", b / "adaptive.json")
    _run(_request(b, cameras, resume=True))
    for name in ("commands.csv",):
        assert (a / "batch-002" / name).read_bytes() == (b / "batch-002" / name).read_bytes()
    # the calibration the run ended with, and microcal fit of the run: the same numbers
    written = load_calibration(a / "calibration.json").manipulators["m1"]
    again = fit(FitRequest(a, tmp_path / "again.json")).entry
    np.testing.assert_array_equal(again.model.coefficients, written.model.coefficients)
    np.testing.assert_array_equal(again.model.covariance, written.model.covariance)
    assert again.validation == written.validation
    assert again.extra["adaptive"] == written.extra["adaptive"]
    assert written.extra["adaptive"]["poses"] == 30
    # the written calibration is the loop's last fit
    assert written.model.inputs == last.inputs
    limits = np.array(json.loads((a / "adaptive.json").read_text())["workspace_um"])
    grid = workspace_grid_um(AdaptiveSettings(until_um=1.0), limits[:, 0], limits[:, 1])
    u = np.hstack([grid, np.ones((len(grid), len(last.inputs) - 3))])
    # the loop read the temperatures from the journal, the file from measurements.csv (4
    # decimals): the models agree to a nanometre
    np.testing.assert_allclose(written.model.predict_um(u), last.predict_um(u), rtol=0, atol=1e-3)


def test_fit_of_an_adaptive_run_refuses_options_of_an_ordinary_fit(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "adaptive.json").write_text("{}", encoding="utf-8")
    with pytest.raises(InputError, match="adaptive run is fitted as its design fits"):
        fit(FitRequest(run, tmp_path / "c.json", train=20))
    with pytest.raises(InputError, match=r"leave out --model matrix"):
        fit(FitRequest(run, tmp_path / "c.json", model="matrix"))
    assert adaptive_fit.MEASUREMENTS == "measurements.csv"


def test_adaptive_needs_a_tolerance_and_cameras(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="until-um"):
        _run(AcquireRequest(tmp_path / "x", rig="sim", design="adaptive", cameras="c.json"))
    with pytest.raises(InputError, match="cameras"):
        _run(AcquireRequest(tmp_path / "y", rig="sim", design="adaptive", until_um=1.0))
