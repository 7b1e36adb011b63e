"""Integrity of a run: what the journal and run.json record is what is measured and resumed.

Each test is a way a run's data was lost or silently changed: a damaged journal line, a
folder with a user's files, swapped or edited inputs, a worse measurement replacing a better
one, a resume that differs from the first part, two processes on one run, temporary files a
stop left. Runs are made once (12 poses on the simulator) and copied per test.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from microcal import sim
from microcal.formats.cameras_file import write_cameras
from support.cli import run_microcal

POSES = 12


def _hashes(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _journal(run: Path) -> list[dict]:
    return [json.loads(x) for x in (run / "journal.jsonl").read_text().splitlines() if x.strip()]


def _measurements_status(run: Path) -> list[str]:
    lines = (run / "measurements.csv").read_text().splitlines()
    column = lines[0].split(",").index("status")
    return [line.split(",")[column] for line in lines[1:]]


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> tuple[Path, Path]:
    """A complete run of 12 poses (2 frames, regions) and the simulator's true cameras."""
    root = tmp_path_factory.mktemp("integrity")
    run = root / "run"
    out = run_microcal("acquire", "--rig", "sim", "--poses", POSES, "--frames", "2",
                       "--store", "roi", "--out", run)  # fmt: skip
    assert out.returncode == 0, out.stderr
    plat = sim.platform("thesis", seed=0)
    cams = {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in plat.camera_models.items()}}  # fmt: skip
    write_cameras(root / "cameras.json", cams)
    return run, root / "cameras.json"


@pytest.fixture
def run(made, tmp_path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(made[0], copy)
    return copy


@pytest.fixture
def cameras(made) -> Path:
    return made[1]


def _fails_cleanly(out: subprocess.CompletedProcess[str], *needles: str) -> str:
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("microcal: error: ")
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_a_damaged_journal_line_costs_only_its_pose_on_resume(run):
    """One corrupted byte in line 5: resume says so, re-acquires pose 5 only, and the seven
    intact lines after it (and their images) are kept byte for byte."""
    journal = run / "journal.jsonl"
    lines = journal.read_bytes().split(b"\n")
    lines[4] = lines[4][:20] + b"\x00" + lines[4][21:]
    journal.write_bytes(b"\n".join(lines))
    images_after = {k: v for k, v in _hashes(run / "images").items() if int(k[-9:-5]) > 5}
    out = run_microcal("acquire", "--out", run, "--resume")
    assert out.returncode == 0, out.stderr
    assert "dropped line 5 (pose 5): not JSON (damaged); its pose is acquired again" in out.stdout
    assert "1 of 12 poses to do" in out.stdout
    new = journal.read_bytes().split(b"\n")
    assert new[4:11] == lines[5:12]  # poses 6..12: the same bytes, in the same order
    assert [r["pose"] for r in _journal(run)] == [1, 2, 3, 4, *range(6, 13), 5]
    after = _hashes(run / "images")
    assert all(after[k] == v for k, v in images_after.items())


def test_measure_names_a_damaged_journal_line_and_measures_the_rest(run, cameras):
    journal = run / "journal.jsonl"
    lines = journal.read_text().splitlines()
    lines[2] = lines[2][:-5]  # pose 3's line cut
    journal.write_text("\n".join(lines) + "\n")
    out = run_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr
    assert "journal.jsonl: line 3 (pose 3): not JSON (damaged)" in out.stdout
    assert "measured 11 of 12 poses" in out.stdout
    assert "pose 3 failed: top: not in the journal, so its images cannot be verified" in out.stdout


def test_a_new_run_never_goes_among_a_users_files(tmp_path):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "commands.csv").write_text("my own commands\n")
    (folder / "images").mkdir()
    (folder / "images" / "top_0001.tiff").write_bytes(b"my own image")
    before = _hashes(folder)
    out = run_microcal("acquire", "--rig", "sim", "--poses", 12, "--out", folder)
    _fails_cleanly(out, "holds other files (commands.csv, images)", "new or empty directory")
    assert _hashes(folder) == before


def test_swapped_images_fail_their_poses_with_the_reason(run, cameras):
    a, b = run / "images" / "top_0003.tiff", run / "images" / "top_0004.tiff"
    data_a, data_b = a.read_bytes(), b.read_bytes()
    a.write_bytes(data_b)
    b.write_bytes(data_a)
    out = run_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr
    assert "measured 10 of 12 poses" in out.stdout
    for pose in (3, 4):
        assert (f"pose {pose} failed: top: {run / 'images' / f'top_000{pose}.tiff'}: changed since "
                f"it was recorded") in out.stdout  # fmt: skip
    assert _measurements_status(run).count("ok") == 10


@pytest.mark.parametrize("edit", ["changed value", "deleted row"])
def test_edited_commands_are_refused_by_measure(run, cameras, edit):
    path = run / "commands.csv"
    rows = path.read_text().splitlines()
    if edit == "changed value":
        rows[3] = rows[3].rsplit(",", 1)[0] + ",1234.5"
    else:
        del rows[6]
    path.write_text("\n".join(rows) + "\n")
    out = run_microcal("measure", run, "--cameras", cameras)
    _fails_cleanly(out, "commands.csv: edited since the run began", "restore the original")
    assert not (run / "measurements.csv").exists()


def test_a_worse_measurement_never_replaces_a_better_one(run, cameras):
    assert run_microcal("measure", run, "--cameras", cameras).returncode == 0
    good = (run / "measurements.csv").read_bytes()
    for pose in range(1, 9):  # the images of 8 poses moved away since
        (run / "images" / f"side_{pose:04d}.tiff").unlink()
    out = run_microcal("measure", run, "--cameras", cameras)
    _fails_cleanly(out, "only 4 of 12 poses measured, fewer than the 12 of the measurements.csv "
                   "it would replace; kept", "--force")  # fmt: skip
    assert (run / "measurements.csv").read_bytes() == good
    out = run_microcal("measure", run, "--cameras", cameras, "--force")
    assert out.returncode == 0, out.stderr
    assert _measurements_status(run).count("ok") == 4


def test_measure_that_measures_nothing_writes_nothing(run, cameras):
    out = run_microcal("measure", run, "--cameras", cameras, "--target", "chessboard:5x4:400")
    _fails_cleanly(out, "no pose measured, all 12 failed", "check --cameras and --target")
    assert not (run / "measurements.csv").exists()


def test_a_resume_needs_no_option_and_keeps_the_first_parts(tmp_path):
    """Begun with --frames 3 --store roi --settle fixed:0.5 and stopped: `--resume` alone
    goes on as begun; an option given again must agree."""
    run = tmp_path / "run"
    args = [sys.executable, "-m", "microcal", "acquire", "--rig", "sim", "--poses", "12",
            "--frames", "3", "--store", "roi", "--settle", "fixed:0.5", "--out", str(run)]  # fmt: skip
    with subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          stdin=subprocess.DEVNULL) as proc:  # fmt: skip
        assert proc.stdout is not None
        for line in proc.stdout:  # bounded: the run prints a handful of lines
            if line.startswith("starting"):
                break
        for _ in range(1200):  # at most a minute
            if proc.poll() is not None or (
                (run / "journal.jsonl").exists() and len(_journal(run)) >= 2
            ):
                break
            time.sleep(0.05)
        proc.terminate()  # the process this test started
        proc.wait(timeout=60)
    done = len(_journal(run))
    assert 0 < done < 12
    out = run_microcal("acquire", "--out", run, "--resume", "--frames", "5")
    _fails_cleanly(out, "--frames 5: this run was begun with --frames 3", "leave --frames out")
    out = run_microcal("acquire", "--out", run, "--resume", "--frames", "3")
    assert out.returncode == 0, out.stderr
    records = _journal(run)
    assert [r["pose"] for r in records] == list(range(1, 13))
    assert {image["frames"] for r in records for image in r["images"].values()} == {3}
    assert {r["settle_s"] for r in records} == {0.5}
    assert all("offset_px" in image for r in records for image in r["images"].values())


def test_a_run_in_use_is_refused_with_the_pid_of_its_holder(run, cameras):
    from microcal.formats.run_lock import run_lock

    before = _hashes(run)
    with run_lock(run, "test"):
        out = run_microcal("acquire", "--out", run, "--resume")
        _fails_cleanly(out, f"in use by microcal (PID {os.getpid()})")
        out = run_microcal("measure", run, "--cameras", cameras)
        _fails_cleanly(out, f"in use by microcal (PID {os.getpid()})")
    assert _hashes(run) == before
    # the lock ends with its holder: the next command runs
    out = run_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr
    assert not (run / ".microcal.lock").exists()


def test_a_lock_left_by_a_killed_process_does_not_block(run, cameras):
    (run / ".microcal.lock").write_text("999999\n")  # a holder that died without unlocking
    out = run_microcal("measure", run, "--cameras", cameras)
    assert out.returncode == 0, out.stderr


def test_resume_removes_the_temporary_files_a_stop_left(run):
    journal = run / "journal.jsonl"
    lines = journal.read_text().splitlines()
    journal.write_text("\n".join(lines[:-1]) + "\n")  # pose 12 was being written
    tmp = run / "images" / ".top_0012.tiff.abc123.tmp"
    tmp.write_bytes(b"half an image")
    out = run_microcal("acquire", "--out", run, "--resume")
    assert out.returncode == 0, out.stderr
    assert f"removed {tmp}, left by a stop while it was written" in out.stdout
    assert not list(run.rglob("*.tmp"))
    assert [r["pose"] for r in _journal(run)] == list(range(1, 13))
