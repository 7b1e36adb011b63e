"""``microcal acquire``: crash safety, faults, resume, refusals, designs on a rig's limits.

What a run records is what it resumes: a damaged journal line costs only its pose, a resume
needs no option and keeps the first part, a stop's temporary files go; a new run never goes
among a user's files.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from microcal import sim
from microcal.formats.cameras_file import write_cameras
from support.cli import invoke_microcal
from support.runs import fails_cleanly, file_hashes, journal_records, write_true_cameras


def fake_rig(tmp_path, faults: str = "") -> str:
    path = tmp_path / "rig.toml"
    path.write_text('driver = "sim"\npreset = "thesis"\nseed = 0\n' + faults)
    return str(path)


def check_run_complete(run, n):
    records = journal_records(run)
    assert sorted(r["pose"] for r in records) == list(range(1, n + 1))  # every pose exactly once
    for r in records:
        for image in r.get("images", {}).values():
            data = (run / image["file"]).read_bytes()
            assert hashlib.sha256(data).hexdigest() == image["sha256"]
    return records


@pytest.mark.slow
def test_crash_safety_kill_and_resume(tmp_path):
    run = tmp_path / "run"
    base = [sys.executable, "-m", "microcal", "acquire", "--rig", "sim", "--poses", "12", "--store", "roi",
            "--frames", "2", "--out", str(run)]  # fmt: skip
    rng = np.random.default_rng(42)
    kills, wanted = 0, 12  # each at a random moment of a run
    for _attempt in range(60):
        args = base + (["--resume"] if (run / "run.json").exists() else [])
        proc = subprocess.Popen(
            args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL
        )
        if kills < wanted:
            time.sleep(rng.uniform(0.5, 3.0))
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)  # only the process this test started
                kills += 1
        proc.wait(timeout=120)
        if proc.returncode == 0 and kills >= wanted:
            break
        if proc.returncode == 0 and len(journal_records(run)) == 12:
            # finished before being killed: start over to keep killing mid-run
            for f in list(run.rglob("*"))[::-1]:
                f.unlink() if f.is_file() else f.rmdir()
            run.rmdir()
    assert kills == wanted
    out = invoke_microcal(
        "acquire", "--rig", "sim", "--poses", "12", "--out", run, "--resume", "--store", "roi"
    )
    assert out.returncode == 0, out.stderr
    assert "0 of 12 poses to do" in out.stdout or "stored 12 of 12" in out.stdout
    check_run_complete(run, 12)
    assert not list(run.rglob("*.tmp"))  # no temporary file left as if it were data


@pytest.mark.slow
def test_faults_are_retried_recorded_and_nothing_is_lost(tmp_path):
    faults = ("[overrides.top.faults]\ndrop_rate = 0.10\nocclusion_rate = 0.05\n"
              "[overrides.side.faults]\ndrop_rate = 0.10\n"
              "[overrides.manipulator.faults]\ntimeout_rate = 0.02\n")  # fmt: skip
    rig = fake_rig(tmp_path, faults)
    run = tmp_path / "run"
    out = invoke_microcal(
        "acquire", "--rig", rig, "--poses", "60", "--frames", "2", "--store", "roi", "--out", run
    )
    assert out.returncode == 0, out.stderr
    assert "stored 60 of 60 poses" in out.stdout
    records = check_run_complete(run, 60)
    failed = [r for r in records if r["status"] == "failed"]
    for r in failed:  # listed with its reason, on the terminal and in the journal
        assert r["reason"]
        assert f"pose {r['pose']} failed: {r['reason']}" in out.stdout
    assert len(failed) < 6  # retries absorb most transient faults (10 % of frames dropped)


@pytest.mark.slow
def test_resume_refuses_another_rig_or_edited_files(tmp_path):
    run = tmp_path / "run"
    assert invoke_microcal("acquire", "--rig", "sim", "--design", "sobol", "--poses", "12", "--frames", "1", "--store", "roi",
                           "--out", run).returncode == 0  # fmt: skip
    out = invoke_microcal("acquire", "--rig", fake_rig(tmp_path, "[overrides.manipulator]\nspeed_um_s = 10.0\n"),
                          "--out", run, "--resume")  # fmt: skip
    assert out.returncode == 2
    assert "made with another rig" in out.stderr
    image = run / "images" / "top_0002.tiff"
    image.write_bytes(image.read_bytes() + b"x")
    out = invoke_microcal("acquire", "--rig", "sim", "--out", run, "--resume")
    assert out.returncode == 2
    assert "missing or changed since it was recorded" in out.stderr
    (run / "commands.csv").write_text((run / "commands.csv").read_text() + "4,1,1,1\n")
    out = invoke_microcal("acquire", "--rig", "sim", "--out", run, "--resume")
    assert "commands.csv was edited" in out.stderr
    out = invoke_microcal("acquire", "--rig", "sim", "--poses", "12", "--out", run)
    assert "already holds a run; use --resume" in out.stderr


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ("dx_um,dy_um,dz_um\n" + "".join(f"{i * 400},{i * 300},100\n" for i in range(20)), "moves axis z over 0 %"),
        ("dx_um,dy_um,dz_um\n0,0,0\n9999,100,100\n4000,4000,4000\n", "axis x = 9999.000 µm is outside the soft limits"),
        ("x,y\n1,2\n", "expected a CSV with columns dx_um,dy_um,dz_um"),
    ],
)  # fmt: skip
def test_bad_designs_exit_2_and_move_nothing(tmp_path, rows, message):
    design = tmp_path / "design.csv"
    design.write_text(rows)
    out = invoke_microcal("acquire", "--rig", "sim", "--design", design, "--out", tmp_path / "run")
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1
    assert message in lines[0]
    assert not (tmp_path / "run").exists()  # nothing created, nothing moved


@pytest.mark.slow
def test_acquire_then_measure(tmp_path):
    run = tmp_path / "run"
    got = invoke_microcal("acquire", "--rig", "sim", "--poses", "12", "--frames", "2", "--store", "roi",
                          "--out", run)  # fmt: skip
    assert got.returncode == 0, got.stderr
    # the regions' disk, unknown before the target is seen, is said after the first pose
    first = [line for line in got.stdout.splitlines() if line.startswith("the first pose took")]
    assert len(first) == 1
    estimate_mb = float(re.search(r"about ([0-9.e+]+) MB for the 12 poses", first[0]).group(1))
    stored_mb = float(
        re.search(r"stored 12 of 12 poses in .* \(([0-9.]+) MB\)", got.stdout).group(1)
    )
    assert 0.7 * stored_mb < estimate_mb < 1.3 * stored_mb
    plat = sim.platform("thesis", seed=0)

    cams = {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in plat.camera_models.items()}}  # fmt: skip
    write_cameras(tmp_path / "cameras.json", cams)
    out = invoke_microcal("measure", run, "--cameras", tmp_path / "cameras.json")
    assert out.returncode == 0, out.stderr
    assert "measured 12 of 12 poses" in out.stdout


@pytest.mark.slow
def test_sigterm_stops_cleanly_and_resume_finishes(tmp_path):
    run = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "microcal", "acquire", "--rig", "sim", "--poses", "40",
                             "--store", "roi", "--frames", "1", "--out", str(run)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)  # fmt: skip
    deadline = time.time() + 60
    while (
        time.time() < deadline
        and len(journal_records(run) if (run / "journal.jsonl").exists() else []) < 3
    ):
        time.sleep(0.1)
    os.kill(proc.pid, signal.SIGTERM)  # only the process this test started
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130  # a stop asked for, as after Ctrl-C; a device fault: 2
    assert "run stopped (stopped on request before pose" in err
    assert "resume with: microcal acquire --out" in err
    stored = len(journal_records(run))
    assert 3 <= stored < 40
    check_run_complete(run, stored)  # what was stored is whole
    out = invoke_microcal(
        "acquire", "--rig", "sim", "--out", run, "--resume", "--store", "roi", "--frames", "1"
    )
    assert out.returncode == 0, out.stderr
    check_run_complete(run, 40)


def test_manipulator_error_stops_the_run_with_how_to_resume(tmp_path):
    rig = fake_rig(tmp_path, "[overrides.manipulator.faults]\nmove_failure_rate = 1.0\n")
    out = invoke_microcal("acquire", "--rig", rig, "--poses", "12", "--out", tmp_path / "run")
    assert out.returncode == 2
    assert "refused the move" in out.stderr
    assert "0 of 12 poses stored; resume with" in out.stderr


def test_evaluation_trajectories_as_designs(tmp_path):
    out = invoke_microcal("acquire", "--rig", "sim", "--design", "table-5-2", "--frames", "1", "--store", "roi",
                          "--settle", "fixed:1", "--out", tmp_path / "run")  # fmt: skip
    assert out.returncode == 0, out.stderr
    records = check_run_complete(tmp_path / "run", 8)
    assert records[0]["commanded_um"] == [2000.0, 0.0, 0.0]
    assert records[0]["settle_s"] == 1.0
    assert records[0]["temperature_c"] == 22.0


def _rows(path):
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow
def test_designs_follow_the_rigs_limits(tmp_path):
    # A rig whose travel is smaller than the thesis's workspace: the design covers its own
    # limits (the old code drew over 0-8000 µm and refused every such rig).
    rig = tmp_path / "small.toml"
    rig.write_text('driver = "sim"\n[overrides.manipulator]\n'
                   "limits_um = [[0.0, 3000.0], [0.0, 3000.0], [0.0, 2000.0]]\n")  # fmt: skip
    out = invoke_microcal("acquire", "--rig", rig, "--poses", "30", "--frames", "1",
                          "--settle", "fixed:1", "--out", tmp_path / "run")  # fmt: skip
    assert out.returncode == 0, out.stderr
    d = np.array([[float(r[c]) for c in ("dx_um", "dy_um", "dz_um")]
                  for r in _rows(tmp_path / "run" / "commands.csv")])  # fmt: skip
    high = np.array([3000.0, 3000.0, 2000.0])
    assert np.all(d >= 0)
    assert np.all(d <= high)
    assert np.all(np.ptp(d, axis=0) > 0.5 * high)  # spread over the travel, not a corner of it
    manifest = json.loads((tmp_path / "run" / "run.json").read_text())
    assert manifest["design"]["high_um"] == high.tolist()
    assert manifest["store"] == "full"


def test_acquire_into_a_file_is_one_line(tmp_path):
    target = tmp_path / "notes.txt"
    target.write_text("mine")
    out = invoke_microcal("acquire", "--rig", "sim", "--out", target, "--poses", "20")
    assert out.returncode == 2
    assert (
        out.stderr.strip()
        == f"microcal: error: --out {target}: is a file; choose a directory for the run"
    )
    assert target.read_text() == "mine"


@pytest.fixture
def run(acquired_run, tmp_path) -> Path:
    """This test's own copy of the session's 12-pose run."""
    return shutil.copytree(acquired_run[0], tmp_path / "run")


def test_a_damaged_journal_line_costs_only_its_pose_on_resume(run):
    """One corrupted byte in line 5: resume says so, re-acquires pose 5 only, and the seven
    intact lines after it (and their images) are kept byte for byte."""
    journal = run / "journal.jsonl"
    lines = journal.read_bytes().split(b"\n")
    lines[4] = lines[4][:20] + b"\x00" + lines[4][21:]
    journal.write_bytes(b"\n".join(lines))
    images_after = {k: v for k, v in file_hashes(run / "images").items() if int(k[-9:-5]) > 5}
    out = invoke_microcal("acquire", "--out", run, "--resume")
    assert out.returncode == 0, out.stderr
    assert "dropped line 5 (pose 5): not JSON (damaged); its pose is acquired again" in out.stdout
    assert "1 of 12 poses to do" in out.stdout
    new = journal.read_bytes().split(b"\n")
    assert new[4:11] == lines[5:12]  # poses 6..12: the same bytes, in the same order
    assert [r["pose"] for r in journal_records(run)] == [1, 2, 3, 4, *range(6, 13), 5]
    after = file_hashes(run / "images")
    assert all(after[k] == v for k, v in images_after.items())


def test_a_new_run_never_goes_among_a_users_files(tmp_path):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "commands.csv").write_text("my own commands\n")
    (folder / "images").mkdir()
    (folder / "images" / "top_0001.tiff").write_bytes(b"my own image")
    before = file_hashes(folder)
    out = invoke_microcal("acquire", "--rig", "sim", "--poses", 12, "--out", folder)
    fails_cleanly(out, "holds other files (commands.csv, images)", "new or empty directory")
    assert file_hashes(folder) == before


@pytest.mark.slow
def test_a_new_run_may_follow_the_cameras_calibrated_into_its_directory(tmp_path):
    """The guide's order: stereo-calibrate --out runs/a/cameras.json, then acquire --out
    runs/a. The cameras (and the views grabbed for them) stay as they were; a file named
    cameras.json that microcal did not write is still someone else's."""
    run = tmp_path / "a"
    run.mkdir()
    write_true_cameras(run / "cameras.json")
    (run / "cameras-views").mkdir()
    (run / "cameras-views" / "steps.csv").write_text("dx_um,dy_um,dz_um\n0,0,0\n")
    before = file_hashes(run)
    out = invoke_microcal("acquire", "--rig", "sim", "--poses", 12, "--frames", 1, "--store",
                          "roi", "--out", run)  # fmt: skip
    assert out.returncode == 0, out.stderr
    after = file_hashes(run)
    assert all(after[k] == v for k, v in before.items())
    assert (run / "run.json").is_file()
    other = tmp_path / "b"
    other.mkdir()
    (other / "cameras.json").write_text('{"mine": true}')
    out = invoke_microcal("acquire", "--rig", "sim", "--poses", 12, "--out", other)
    fails_cleanly(out, "holds other files (cameras.json)", "new or empty directory")


@pytest.mark.slow
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
                (run / "journal.jsonl").exists() and len(journal_records(run)) >= 2
            ):
                break
            time.sleep(0.05)
        proc.terminate()  # the process this test started
        proc.wait(timeout=60)
    done = len(journal_records(run))
    assert 0 < done < 12
    out = invoke_microcal("acquire", "--out", run, "--resume", "--frames", "5")
    fails_cleanly(out, "--frames 5: this run was begun with --frames 3", "leave --frames out")
    out = invoke_microcal("acquire", "--out", run, "--resume", "--frames", "3")
    assert out.returncode == 0, out.stderr
    records = journal_records(run)
    assert [r["pose"] for r in records] == list(range(1, 13))
    assert {image["frames"] for r in records for image in r["images"].values()} == {3}
    assert {r["settle_s"] for r in records} == {0.5}
    assert all("offset_px" in image for r in records for image in r["images"].values())


def test_resume_removes_the_temporary_files_a_stop_left(run):
    journal = run / "journal.jsonl"
    lines = journal.read_text().splitlines()
    journal.write_text("\n".join(lines[:-1]) + "\n")  # pose 12 was being written
    tmp = run / "images" / ".top_0012.tiff.abc123.tmp"
    tmp.write_bytes(b"half an image")
    out = invoke_microcal("acquire", "--out", run, "--resume")
    assert out.returncode == 0, out.stderr
    assert f"removed {tmp}, left by a stop while it was written" in out.stdout
    assert not list(run.rglob("*.tmp"))
    assert [r["pose"] for r in journal_records(run)] == list(range(1, 13))
