"""``microcal acquire --design adaptive``: batches acquired, measured and chosen in turn;
a run stopped between batches or within one resumes without losing a pose, and chooses the
poses the run would have chosen without the stop."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from microcal.errors import InputError
from microcal.formats.run_directory import RunDirectory, RunWriter
from microcal.workflows import adaptive_acquire
from microcal.workflows.acquire import AcquireRequest
from microcal.workflows.adaptive_acquire import acquire_any
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
    assert "30 poses in 2 batches" in lines[-1]
    assert len(RunDirectory.open(crashed / "batch-002").commands()[0]) == 10
    options = json.loads((crashed / "adaptive.json").read_text(encoding="utf-8"))
    assert options["until_um"] == 0.01


def test_the_same_measurements_choose_the_same_batch(tmp_path: Path) -> None:
    cameras = write_true_cameras(tmp_path / "cameras.json")
    a, b = tmp_path / "a", tmp_path / "b"
    _run(_request(a, cameras))
    b.mkdir()
    shutil.copytree(a / "batch-001", b / "batch-001")
    shutil.copy(a / "adaptive.json", b / "adaptive.json")
    _run(_request(b, cameras, resume=True))
    for name in ("commands.csv",):
        assert (a / "batch-002" / name).read_bytes() == (b / "batch-002" / name).read_bytes()


def test_adaptive_needs_a_tolerance_and_cameras(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="until-um"):
        _run(AcquireRequest(tmp_path / "x", rig="sim", design="adaptive", cameras="c.json"))
    with pytest.raises(InputError, match="cameras"):
        _run(AcquireRequest(tmp_path / "y", rig="sim", design="adaptive", until_um=1.0))
