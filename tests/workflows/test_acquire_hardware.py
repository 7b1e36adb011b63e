"""Acquisition runs end to end through the real drivers and their protocol peers.

The MCS2 driver talks TCP to the fake controller; the top camera is Debian's fake GigE Vision
camera and the side camera viva-genicam's, both through Aravis over UDP. Everything runs on
loopback inside the test's own network namespace (the ``netns`` fixture).
"""

from __future__ import annotations

import hashlib
import json
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from microcal.cli import app

runner = CliRunner()

MCS2_RIG = """
driver = "hardware"
board = "chessboard:4x3:400"

[manipulator]
kind = "smaract-mcs2"
address = "127.0.0.1"
timeout_s = 0.5
channels = {{ x = 0, y = 1, z = 2 }}
limits_um = {{ x = [0, 8000], y = [0, 8000], z = [0, 4800] }}

[cameras.top]
kind = "aravis"
address = "127.0.0.1"
exposure_ms = 5
timeout_s = {timeout_s}

[cameras.side]
kind = "aravis"
address = "127.0.0.2"
exposure_ms = 5
timeout_s = {timeout_s}
"""


@pytest.fixture
def rig(tmp_path, fake_mcs2, gige_cameras):
    """(rig file, fake controller, top camera process) with every peer running."""
    top = gige_cameras("127.0.0.1", serial="TOP01")
    gige_cameras("127.0.0.2", viva=(1226, 1028))
    path = tmp_path / "rig.toml"
    path.write_text(MCS2_RIG.format(timeout_s=0.5))
    return path, fake_mcs2, top


def _stored(line: str) -> bool:
    """True for a complete journal line of a stored pose (a line being written is not)."""
    try:
        return json.loads(line).get("status") == "ok"
    except ValueError:
        return False


def journal(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "journal.jsonl").read_text().splitlines()]


def acquire(*args: str):
    return runner.invoke(app, ["acquire", *args], env={"COLUMNS": "200"})


@pytest.mark.slow
def test_twenty_poses_end_to_end_through_the_drivers(rig, tmp_path):
    path, fake, _ = rig
    run = tmp_path / "run"
    t0 = time.monotonic()
    result = acquire("--rig", str(path), "--design", "random", "--poses", "20", "--seed", "4",
                     "--settle", "fixed:0.05", "--frames", "2", "--out", str(run))  # fmt: skip
    assert result.exit_code == 0, result.output
    assert time.monotonic() - t0 < 60
    records = journal(run)
    assert [r["pose"] for r in records] == list(range(1, 21))
    assert all(r["status"] == "ok" for r in records)
    commands = np.loadtxt(run / "commands.csv", delimiter=",", skiprows=1)[:, 1:]
    for r, d in zip(records, commands, strict=True):
        np.testing.assert_allclose(r["commanded_um"], d)
        np.testing.assert_allclose(r["reported_um"], d, atol=1e-6)  # the controller's sensors
        for cam, shape in (("top", (512, 512)), ("side", (1028, 1226))):
            image = run / r["images"][cam]["file"]
            assert hashlib.sha256(image.read_bytes()).hexdigest() == r["images"][cam]["sha256"]
            pages = tifffile.imread(image)
            assert pages.shape == (2, *shape)
    last = [c.target_pm / 1e6 for c in fake.channels]
    np.testing.assert_allclose(last, commands[-1], atol=1e-6)
    manifest = json.loads((run / "run.json").read_text())
    assert manifest["rig"]["manipulator"]["kind"] == "smaract-mcs2"
    assert manifest["cameras"] == ["top", "side"]


@pytest.mark.slow
def test_dropped_connection_mid_move_is_reconnected_and_the_run_completes(rig, tmp_path):
    path, fake, _ = rig
    fake.faults.drop_after_move = 8  # pose 3's second axis
    run = tmp_path / "run"
    result = acquire("--rig", str(path), "--poses", "12", "--settle", "fixed:0.05", "--frames",
                     "1", "--out", str(run))  # fmt: skip
    assert result.exit_code == 0, result.output
    assert [r["status"] for r in journal(run)] == ["ok"] * 12
    assert fake.connections == 2


@pytest.mark.slow
def test_a_controller_error_stops_the_run_cleanly_and_resume_completes_it(rig, tmp_path):
    path, fake, _ = rig
    fake.faults.fail_after_moves = 7  # pose 3, axis x
    run = tmp_path / "run"
    args = ["--rig", str(path), "--poses", "12", "--settle", "fixed:0.05", "--frames", "1",
            "--out", str(run)]  # fmt: skip
    result = acquire(*args)
    assert result.exit_code == 2
    line = result.stderr.strip()
    assert len(line.splitlines()) == 1
    assert (
        "run stopped (pose 3: mcs2: axis x (channel 0): movement failed; controller: -1015" in line
    )
    assert "2 of 12 poses stored" in line
    assert "--resume" in line
    assert "Traceback" not in result.output
    assert [r["pose"] for r in journal(run)] == [1, 2]
    result = acquire(*args, "--resume")
    assert result.exit_code == 0, result.output
    records = journal(run)
    assert [r["pose"] for r in records] == list(range(1, 13))
    assert all(r["status"] == "ok" for r in records)


@pytest.mark.slow
def test_a_camera_that_stops_answering_stops_the_run_cleanly_and_resume_completes(rig, tmp_path):
    path, _, top = rig
    run = tmp_path / "run"
    args = ["--rig", str(path), "--poses", "12", "--settle", "fixed:0.2", "--frames", "1",
            "--out", str(run)]  # fmt: skip
    done = threading.Event()

    def stop_the_camera_after_the_first_pose() -> None:
        # the camera stops once a pose is stored, whatever the machine's load (bounded wait)
        for _ in range(600):
            if done.is_set():
                return
            path = run / "journal.jsonl"
            if any(
                _stored(line) for line in (path.read_text() if path.exists() else "").split("\n")
            ):
                top.send_signal(signal.SIGSTOP)
                return
            time.sleep(0.05)

    stopper = threading.Thread(target=stop_the_camera_after_the_first_pose)
    stopper.start()
    t0 = time.monotonic()
    try:
        result = acquire(*args)
    finally:
        done.set()
        stopper.join()
    elapsed = time.monotonic() - t0
    top.send_signal(signal.SIGCONT)
    assert result.exit_code == 2, result.output
    line = result.stderr.strip()
    assert len(line.splitlines()) == 1
    assert "3 poses in a row failed" in line
    assert "top: camera not answering" in line
    assert "--resume" in line
    records = journal(run)
    assert records[0]["status"] == "ok"
    assert [r["status"] for r in records[-3:]] == ["failed"] * 3
    for r in records[-3:]:
        assert r["reason"].startswith("top: camera not answering"), r["reason"]
    # each failed pose costs the camera's own timeouts, never more: no hang
    assert elapsed < 30
    result = acquire(*args, "--resume")
    assert result.exit_code == 0, result.output
    records = journal(run)
    assert [r["pose"] for r in records] == list(range(1, 13))  # every pose once
    assert records[-1]["status"] == "ok"


def test_dry_run_checks_every_device_and_moves_nothing(rig, tmp_path):
    path, fake, _ = rig
    run = tmp_path / "run"
    result = acquire("--rig", str(path), "--poses", "20", "--out", str(run), "--dry-run")
    assert result.exit_code == 0, result.output
    out = result.output
    assert "manipulator: SmarAct MCS2 MCS2-FAKE0001 at 127.0.0.1" in out
    assert "top: Aravis Fake TOP01 at 127.0.0.1" in out
    assert "side: vitavision.dev VivaCam Fake" in out
    assert "camera top: 512 x 512 px, uint8" in out
    assert "camera side: 1226 x 1028 px, uint8" in out
    assert "board not found" in out  # the fakes show test patterns, not the board
    assert "design random: 20 poses, all within the soft limits" in out
    assert "dry run: nothing moved, nothing written" in out
    assert not any(c.startswith(":MOVE") for c in fake.log)
    assert not run.exists()


def test_dry_run_without_the_controller_is_one_line(netns, tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(MCS2_RIG.format(timeout_s=0.5))
    result = acquire("--rig", str(path), "--out", str(tmp_path / "run"), "--dry-run")
    assert result.exit_code == 2
    assert result.stderr.strip() == (
        "microcal: error: mcs2: cannot connect to 127.0.0.1:55551 (Connection refused)"
    )


MM_RIG = """
driver = "hardware"

[micromanager]
python_devices = "support.mm_devices:load"

[manipulator]
kind = "micromanager"
xy_stage = "XY"
focus = "Z"
limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }

[cameras.top]
kind = "micromanager"
device = "TopCam"
exposure_ms = 5

[cameras.side]
kind = "micromanager"
device = "SideCam"
"""


def test_micro_manager_rig_acquires(tmp_path):
    pytest.importorskip("pymmcore_plus", reason="needs pymmcore-plus (pip install 'microcal[mm]')")
    path = tmp_path / "mm.toml"
    path.write_text(MM_RIG)
    result = acquire("--rig", str(path), "--out", str(tmp_path / "x"), "--dry-run")
    assert result.exit_code == 0, result.output
    assert "manipulator: Micro-Manager XY + Z" in result.output
    run = tmp_path / "run"
    result = acquire("--rig", str(path), "--poses", "12", "--settle", "fixed:0.01", "--frames",
                     "1", "--out", str(run))  # fmt: skip
    assert result.exit_code == 0, result.output
    records = journal(run)
    assert [r["status"] for r in records] == ["ok"] * 12
    assert tifffile.imread(run / records[0]["images"]["side"]["file"]).shape[-2:] == (103, 123)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('kind = "smaract-mcs2"', 'kind = "pi-gcs"'), "manipulator.kind"),
        (
            lambda t: t.replace(", z = [0, 4800]", ""),
            "limits_um: expected a [low, high] for each of",
        ),
        (lambda t: t.replace('address = "127.0.0.2"', ""), "cameras.side: aravis needs 'address'"),
        (lambda t: t.replace("exposure_ms = 5", "exposure_ms = -5", 1), "cameras.top.exposure_ms"),
        (lambda t: t + "\n[extra]\nx = 1\n", "extra"),
    ],
)
def test_rig_file_mistakes_are_one_line_naming_the_key(tmp_path, edit, message):
    path = tmp_path / "rig.toml"
    path.write_text(edit(MCS2_RIG.format(timeout_s=0.5)))
    result = acquire("--rig", str(path), "--out", str(tmp_path / "run"), "--dry-run")
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1
    assert message in lines[0]
