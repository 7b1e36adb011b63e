"""The run directory: written crash-safely by RunWriter, read back by RunDirectory; and the one
reader of joint-command CSV files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from microcal import FormatError, InputError
from microcal.formats.commands_csv import read_joint_csv
from microcal.formats.records import JournalLine, RoiRecord, RunManifest
from microcal.formats.run_directory import RunDirectory, RunWriter, read_commands
from microcal.journal_record import JournalRecord, PoseStatus
from microcal.vision.measurement import PoseMeasurement

RIG = {"driver": "sim", "preset": "thesis", "seed": 0, "overrides": {}}
FULL_H, FULL_W = 40, 60
D_UM = np.array([[100.0, 200.0, 300.0], [1100.0, 1200.0, 1300.0], [2100.0, 2200.0, 2300.0]])


def _manifest() -> dict[str, object]:
    return {
        "rig": RIG,
        "target": "chessboard:4x3:400",
        "cameras": ["top", "side"],
        "design": {"kind": "random", "poses": 3, "seed": 7},
        "settle": "vision",
        "frames_per_pose": 2,
        "store": "roi",
        "provenance": {"command": "test"},
    }


def _frames(seed: int, shape: tuple[int, int]) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 4096, shape, dtype=np.uint16) for _ in range(2)]


def _record(
    pose: int,
    status: PoseStatus = "ok",
    *,
    reason: str | None = None,
    readings: dict[str, float] | None = None,
    roi_px: dict[str, tuple[int, int, int, int]] | None = None,
) -> JournalRecord:
    return JournalRecord(pose=pose, commanded_um=D_UM[pose - 1].tolist(), approach={},
                         status=status, wall_time_s=1700000000.0 + pose, sim_time_s=10.0 * pose,
                         move_s=0.5, settle_s=1.5 * pose, residual_px=None, reason=reason,
                         roi_px=roi_px or {}, readings=readings or {})  # fmt: skip


@pytest.fixture
def run(tmp_path: Path) -> tuple[Path, dict[str, list[np.ndarray]]]:
    """Pose 1 stored (top full frames, side a region at (10, 5)), pose 2 failed, pose 3 not
    acquired; (directory, the frames given to the writer)."""
    out = tmp_path / "run"
    writer = RunDirectory.create(out, _manifest(), D_UM)
    frames = {"top": _frames(1, (FULL_H, FULL_W)), "side": _frames(2, (12, 20))}
    record = _record(1, readings={"temperature_c": 21.5}, roi_px={"side": (10, 5, FULL_W, FULL_H)})
    writer.store(1, {k: list(v) for k, v in frames.items()}, record)
    writer.store(2, {}, _record(2, "failed", reason="move timed out"))
    return out, frames


def test_a_run_reads_back_its_commands_manifest_and_journal(run):
    out, _ = run
    rd = RunDirectory.open(out)
    assert rd.path == out
    poses, d = rd.commands()
    assert poses == [1, 2, 3]
    np.testing.assert_array_equal(d, D_UM)
    assert read_commands(out)[0] == poses
    manifest = rd.manifest
    assert isinstance(manifest, RunManifest)
    assert manifest.format == "microcal.run/1"
    assert manifest.rig == RIG
    assert manifest.design is not None
    assert manifest.design.seed == 7
    assert manifest.commands_sha256 is not None
    assert len(manifest.commands_sha256) == 64
    assert rd.target_spec == "chessboard:4x3:400"
    journal = rd.journal()
    assert list(journal) == [1, 2]
    assert all(isinstance(line, JournalLine) for line in journal.values())
    assert journal[1].images["side"].roi == RoiRecord((10, 5), (FULL_W, FULL_H))
    assert journal[1].images["top"].roi is None
    assert journal[2].failed
    assert journal[2].reason == "move timed out"
    assert journal[1].get("commanded_um") == D_UM[0].tolist()  # other keys are kept


def test_the_journal_keeps_its_keys(run):
    out, _ = run
    line = json.loads((out / "journal.jsonl").read_text().splitlines()[0])
    side = line["images"]["side"]
    assert side["offset_px"] == [10, 5]
    assert side["full_size_px"] == [FULL_W, FULL_H]
    assert side["file"] == "images/side_0001.tiff"
    assert side["frames"] == 2
    assert len(side["sha256"]) == 64
    assert "offset_px" not in line["images"]["top"]
    assert line["temperature_c"] == 21.5
    assert "roi_px" not in line  # recorded with the image instead
    # the record's keys in the acquisition's order, then the images
    assert list(line) == ["pose", "commanded_um", "status", "time", "sim_time_s", "move_s",
                          "settle_s", "residual_px", "temperature_c", "images"]  # fmt: skip


def test_frames_of_a_full_frame_and_of_a_stored_region(run):
    out, given = run
    rd = RunDirectory.open(out)
    top = rd.frames(1, "top")
    assert len(top) == 2
    for got, want in zip(top, given["top"], strict=True):
        np.testing.assert_array_equal(got, want)
    side = rd.frames(1, "side")
    for got, region in zip(side, given["side"], strict=True):
        assert got.shape == (FULL_H, FULL_W)
        assert got.dtype == region.dtype
        np.testing.assert_array_equal(got[5:17, 10:30], region)  # pasted at (x0, y0) = (10, 5)
        outside = np.ones(got.shape, bool)
        outside[5:17, 10:30] = False
        assert np.all(got[outside] == np.median(region.astype(float)).astype(region.dtype))


def test_frames_of_a_failed_or_missing_pose_say_why(run):
    out, _ = run
    rd = RunDirectory.open(out)
    with pytest.raises(FormatError, match=r"^acquisition failed: move timed out$"):
        rd.frames(2, "top")
    with pytest.raises(FormatError, match=r"^no image images/top_0003\.tiff$"):
        rd.frames(3, "top")


def test_temperature_is_journaled_per_pose(run, tmp_path):
    out, _ = run
    rd = RunDirectory.open(out)
    t = rd.temperature_c([1, 2, 3])
    assert t is not None
    np.testing.assert_array_equal(t, [21.5, np.nan, np.nan])
    assert set(rd.extra_inputs([1, 2, 3])) == {"temperature"}
    other = tmp_path / "cold"
    RunDirectory.create(other, _manifest(), D_UM).store(1, {}, _record(1))
    assert RunDirectory.open(other).temperature_c([1, 2, 3]) is None


def test_measurements_carry_the_temperature(run):
    out, _ = run
    rd = RunDirectory.open(out)
    poses, d = rd.commands()
    results = [PoseMeasurement(1, "ok", p_um=np.array([1.0, 2.0, 3.0]), cov_um2=np.eye(3)),
               PoseMeasurement(2, "failed", "top: acquisition failed: move timed out"),
               PoseMeasurement(3, "failed", "top: no image")]  # fmt: skip
    path = rd.write_measurements(poses, d, results)
    assert path == rd.measurements_path == out / "measurements.csv"
    from microcal.formats.measurements import read_measurements

    meas = read_measurements(path)
    assert meas.pose.tolist() == [1]
    assert meas.temperature_c is not None
    assert meas.temperature_c.tolist() == [21.5]
    assert meas.failed_reasons[2] == "top: acquisition failed: move timed out"


def test_files_lists_what_exists_in_run_order(run):
    out, _ = run
    rd = RunDirectory.open(out)
    names = [str(p.relative_to(out)) for p in rd.files()]
    assert names == ["run.json", "commands.csv", "journal.jsonl", "images/side_0001.tiff",
                     "images/top_0001.tiff"]  # fmt: skip
    (out / "results.json").write_text("{}")
    (out / "notes.txt").write_text("not a run file")
    assert rd.files()[-1] == out / "results.json"


def test_open_refuses_what_is_not_a_run(tmp_path):
    with pytest.raises(InputError, match=f"{tmp_path / 'none'}: not a directory"):
        RunDirectory.open(tmp_path / "none")
    with pytest.raises(FormatError, match=r"commands\.csv: no such file"):
        RunDirectory.open(tmp_path)
    deferred = RunDirectory.open(tmp_path, require_commands=False)
    with pytest.raises(FormatError, match=r"commands\.csv: no such file"):
        deferred.commands()
    empty = RunDirectory(tmp_path)  # as the report takes it: whatever it holds
    assert empty.manifest is None
    assert empty.target_spec is None
    assert empty.journal() == {}
    assert empty.files() == []


def test_a_manifest_of_another_version_is_named(run):
    out, _ = run
    raw = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps({**raw, "format": "microcal.run/2"}))
    with pytest.raises(
        FormatError, match=r"microcal.run version '2' is not one .* reads version 1"
    ):
        _ = RunDirectory.open(out).manifest


def test_create_takes_a_typed_manifest_and_refuses_a_second_run(tmp_path):
    out = tmp_path / "run"
    writer = RunWriter.create(out, RunManifest.model_validate(_manifest()), D_UM)
    raw = json.loads((out / "run.json").read_text())
    assert list(raw) == ["format", *_manifest(), "commands_sha256"]
    assert writer.manifest.rig == RIG
    with pytest.raises(FormatError, match="already holds a run"):
        RunDirectory.create(out, _manifest(), D_UM)
    with pytest.raises(FormatError, match=r"design\.poses: Field required"):
        RunDirectory.create(tmp_path / "bad", {**_manifest(), "design": {"kind": "x"}}, D_UM)
    assert not (tmp_path / "bad" / "commands.csv").exists()


def test_resume_continues_where_the_journal_ends(run):
    out, _ = run
    with open(out / "journal.jsonl", "a") as fh:
        fh.write('{"pose": 3, "sta')  # cut by a crash
    writer = RunDirectory.resume(out, RIG)
    assert sorted(writer.done) == [1, 2]
    assert writer.remaining([1, 2, 3]) == [3]
    assert (out / "journal.jsonl").read_text().endswith("}\n")
    with pytest.raises(FormatError, match="made with another rig"):
        RunDirectory.resume(out, {**RIG, "seed": 1})
    (out / "images" / "top_0001.tiff").write_bytes(b"changed")
    with pytest.raises(FormatError, match=r"top_0001\.tiff: missing or changed"):
        RunDirectory.resume(out, RIG)


def test_resume_refuses_edited_commands(run):
    out, _ = run
    (out / "commands.csv").write_text("pose,dx_um,dy_um,dz_um\n1,0,0,0\n")
    with pytest.raises(FormatError, match="was edited since the run began"):
        RunDirectory.resume(out, RIG)


def test_a_pose_journaled_twice_is_damage_and_the_first_line_counts(run):
    out, _ = run
    lines = (out / "journal.jsonl").read_text().splitlines()
    with open(out / "journal.jsonl", "a") as fh:
        fh.write(lines[0] + "\n")
    directory = RunDirectory.open(out)
    assert list(directory.journal()) == [1, 2]
    damage = directory.journal_damage()
    assert [(d.number, d.reason, d.pose) for d in damage] == [(len(lines) + 1, "pose 1 again", 1)]


# --- the joint-command CSV reader -----------------------------------------------------------
def _csv(tmp_path: Path, text: str, encoding: str = "utf-8") -> Path:
    path = tmp_path / "d.csv"
    path.write_bytes(text.encode(encoding))
    return path


def test_csv_with_or_without_byte_order_mark(tmp_path):
    text = "pose,dx_um,dy_um,dz_um,note\r\n1,1,2,3,a\r\n2,4,5,6e1,b\r\n\r\n"
    for encoding in ("utf-8", "utf-8-sig"):
        poses, d = read_joint_csv(_csv(tmp_path, text, encoding), what="--design")
        assert poses == [1, 2]
        np.testing.assert_array_equal(d, [[1, 2, 3], [4, 5, 60]])
    poses, d = read_joint_csv(_csv(tmp_path, "dx_um,dy_um,dz_um\n1,2,3\n"))
    assert poses is None
    assert d.shape == (1, 3)
    assert read_joint_csv(_csv(tmp_path, text), pose_column=False)[0] is None


@pytest.mark.parametrize(
    ("text", "kwargs", "match"),
    [
        ("dx_um,dy_um,dz_um\n1,2,3\n4,x,6\n", {}, r"^--design .*d\.csv, line 3: dy_um = 'x' is not a number$"),
        ("dx_um,dy_um,dz_um\n1,2,3\n4,nan,6\n", {}, r"line 3: dy_um = 'nan' is not a finite number"),
        ("dx_um,dy_um,dz_um\n1,2,inf\n", {}, r"line 2: dz_um = 'inf' is not a finite number"),
        ("pose,dx_um,dy_um,dz_um\n1,1,2,3\n2,1,2,3\n1,1,2,3\n", {}, r"line 4: pose 1 appears twice \(first on line 2\)"),
        ("pose,dx_um,dy_um,dz_um\n1.5,1,2,3\n", {}, r"line 2: pose '1.5' is not a whole number"),
        ("pose,dx_um,dy_um,dz_um\n0,1,2,3\n", {}, r"line 2: pose 0; poses are numbered from 1"),
        ("dx_um,dy_um\n1,2\n", {}, r"line 1: missing column\(s\) \['dz_um'\]"),
        ("dx_um,dy_um,dz_um\n1,2,3\n", {"pose_column": True}, r"missing column\(s\) \['pose'\]"),
        ("dx_um,dy_um,dz_um\n1,2\n", {}, r"line 2: 2 cells, expected 3"),
        ("dx_um,dy_um,dz_um\n1,2,3\n", {"rows": 5}, r"1 rows of dx_um,dy_um,dz_um, expected 5$"),
        ("dx_um,dy_um,dz_um\n", {}, r"0 rows of dx_um,dy_um,dz_um, expected at least 1"),
        ("", {}, r"empty; expected a header dx_um,dy_um,dz_um"),
    ],
)  # fmt: skip
def test_csv_errors_name_the_file_and_line(tmp_path, text, kwargs, match):
    with pytest.raises(InputError, match=match):
        read_joint_csv(_csv(tmp_path, text), what="--design", **kwargs)


def test_csv_errors_of_run_files_are_format_errors(tmp_path):
    with pytest.raises(FormatError, match=r"d\.csv: no such file"):
        read_joint_csv(tmp_path / "d.csv", error=FormatError)
    path = tmp_path / "d.csv"
    path.write_bytes(b"dx_um,dy_um,dz_um\n1,2,\xff\n")
    with pytest.raises(FormatError, match="not UTF-8 text"):
        read_joint_csv(path, error=FormatError)
    run = tmp_path / "run"
    RunDirectory.create(run, _manifest(), D_UM)
    (run / "run.json").unlink()  # a run made by hand: no SHA-256 of its commands
    (run / "commands.csv").write_text("pose,dx_um,dy_um,dz_um\n1,1,2,3\n1,4,5,6\n")
    with pytest.raises(FormatError, match=r"commands\.csv, line 3: pose 1 appears twice"):
        RunDirectory.open(run).commands()
