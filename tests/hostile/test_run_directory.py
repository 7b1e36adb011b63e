"""A run directory is data a lab copies, shares and downloads: what it may not make microcal do.

- a resume never imports a module nor connects to an address the run records: a recorded
  hardware rig needs the user's own ``--rig`` file, compared with the record before any
  device is opened;
- a name or a path a run (run.json, its journal), cameras.json or a rig file gives stays
  inside its folder: camera and device names are plain words, a journal's image is its
  pose's file in ``images/``;
- a size or a count a run declares is bounded before anything is allocated from it;
- a resume never writes over an image: those of a pose it acquires again are kept aside.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import socket
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from support.hostile import Sandbox, kept_outside, refused_cleanly, run_traced
from support.runs import journal_records

LIMITS = {"x": [0.0, 8000.0], "y": [0.0, 8000.0], "z": [0.0, 4800.0]}


# --- making the inputs ---------------------------------------------------------------------
@pytest.fixture
def box(tmp_path: Path) -> Sandbox:
    return Sandbox.make(tmp_path)


@pytest.fixture
def run(acquired_run: tuple[Path, Path], box: Sandbox) -> Path:
    """A copy of the session's simulated run (12 poses, 2 frames, regions) in the case."""
    return Path(shutil.copytree(acquired_run[0], box.case / "run"))


@pytest.fixture
def cameras(acquired_run: tuple[Path, Path], box: Sandbox) -> Path:
    """The simulator's true cameras.json, in the case."""
    return Path(shutil.copy(acquired_run[1], box.case / "cameras.json"))


@pytest.fixture
def listener() -> Iterator[socket.socket]:
    """A TCP port on this machine that counts who connects to it (nothing answers)."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    try:
        yield server
    finally:
        server.close()


def connections(server: socket.socket) -> int:
    """How many connections ``server`` has waiting (each accepted and closed)."""
    server.setblocking(False)
    count = 0
    while True:
        try:
            conn, _ = server.accept()
        except BlockingIOError:
            return count
        conn.close()
        count += 1


def edit_json(path: Path, edit: Callable[[dict[str, Any]], None]) -> None:
    data = json.loads(path.read_text(encoding="utf-8"))
    edit(data)
    path.write_text(json.dumps(data, indent=1), encoding="utf-8")


def edit_journal(run: Path, edit: Callable[[list[dict[str, Any]]], None]) -> None:
    records = journal_records(run)
    edit(records)
    text = "".join(json.dumps(r) + "\n" for r in records)
    (run / "journal.jsonl").write_text(text, encoding="utf-8")


def record_rig(run: Path, rig: dict[str, Any]) -> None:
    """run.json records ``rig`` (as if the run had been made on it)."""
    edit_json(run / "run.json", lambda m: m.update(rig=rig))


def mcs2_rig(port: int) -> dict[str, Any]:
    """A hardware rig's record: a SmarAct controller on this machine's ``port``."""
    camera = {"kind": "aravis", "address": "127.0.0.1", "pixel_format": "Mono8",
              "timeout_s": 0.2, "pixel_size_um": 3.45}  # fmt: skip
    return {
        "driver": "hardware",
        "board": "chessboard:4x3:400",
        "manipulator": {
            "kind": "smaract-mcs2",
            "limits_um": LIMITS,
            "address": "127.0.0.1",
            "port": port,
            "channels": {"x": 0, "y": 1, "z": 2},
            "timeout_s": 0.2,
            "reconnects": 0,
        },
        "cameras": {"top": camera, "side": dict(camera)},
    }


def mcs2_rig_file(path: Path, port: int, cameras: tuple[str, str] = ("top", "side")) -> Path:
    """The rig file of :func:`mcs2_rig` (cameras named ``cameras``)."""
    tables = "\n".join(
        f'[cameras."{name}"]\nkind = "aravis"\naddress = "127.0.0.1"\ntimeout_s = 0.2\n'
        for name in cameras
    )
    path.write_text(
        'driver = "hardware"\nboard = "chessboard:4x3:400"\n[manipulator]\n'
        'kind = "smaract-mcs2"\naddress = "127.0.0.1"\n'
        f"port = {port}\ntimeout_s = 0.2\nreconnects = 0\n"
        "channels = { x = 0, y = 1, z = 2 }\n"
        "limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }\n" + tables,
        encoding="utf-8",
    )
    return path


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def resume(run: Path, *extra: object) -> Callable[[], Any]:
    return lambda: run_traced("acquire", "--out", run, "--resume", *extra)


def measure(run: Path, cameras: Path) -> Callable[[], Any]:
    return lambda: run_traced("measure", run, "--cameras", cameras)


# --- 1. a resume imports and connects to nothing the user did not name ----------------------
def test_a_resume_imports_no_module_the_run_records(run, box, monkeypatch):
    """run.json records a Micro-Manager rig whose pure-Python devices are a module of the
    run's sender: a resume without --rig must not import it (here it would write outside)."""
    module = "hostile_run_devices_7f3a"
    (box.case / f"{module}.py").write_text(
        f"from pathlib import Path\nPath({str(box.outside / 'imported.txt')!r}).write_text('x')\n"
        "def load(core, **options):\n    pass\n",
        encoding="utf-8",
    )
    monkeypatch.syspath_prepend(str(box.case))
    monkeypatch.delitem(sys.modules, module, raising=False)
    camera = {"kind": "micromanager", "device": "Cam", "pixel_format": "Mono8",
              "timeout_s": 2.0, "pixel_size_um": 3.45}  # fmt: skip
    record_rig(run, {
        "driver": "hardware",
        "board": "chessboard:4x3:400",
        "manipulator": {"kind": "micromanager", "limits_um": LIMITS, "port": 55551,
                        "timeout_s": 2.0, "reconnects": 2, "xy_stage": "XY", "focus": "Z"},
        "cameras": {"top": camera, "side": dict(camera)},
        "micromanager": {"python_devices": f"{module}:load"},
    })  # fmt: skip
    refused_cleanly(box, resume(run), "run.json", "hardware rig", "pass --rig")
    assert module not in sys.modules


def test_a_resume_connects_to_no_address_the_run_records(run, box, listener):
    record_rig(run, mcs2_rig(listener.getsockname()[1]))
    refused_cleanly(box, resume(run), "run.json", "hardware rig", "pass --rig")
    assert connections(listener) == 0


def test_a_resume_on_another_rig_is_refused_before_any_device_opens(run, box, listener):
    """The user's --rig is compared with the recorded one before it is opened: a rig file
    that is not the run's connects nowhere."""
    record_rig(run, mcs2_rig(listener.getsockname()[1] + 1))  # the run's: another port
    rig = mcs2_rig_file(box.case / "rig.toml", listener.getsockname()[1])
    line = refused_cleanly(box, resume(run, "--rig", rig), "made with another rig", "--rig")
    assert "127.0.0.1" not in line  # the record's settings are not quoted
    assert connections(listener) == 0


# --- 2. names and paths stay inside ---------------------------------------------------------
def test_a_rig_file_camera_named_as_a_path_is_refused(box, listener):
    rig = mcs2_rig_file(box.case / "rig.toml", listener.getsockname()[1], ("../x", "side"))
    act = lambda: run_traced("acquire", "--rig", rig, "--poses", 12, "--out", box.case / "run")  # noqa: E731
    refused_cleanly(box, act, "rig.toml", "cameras", "is not a name")
    assert connections(listener) == 0


def test_a_rig_file_micromanager_config_outside_its_folder_is_refused(box):
    (box.outside / "MMConfig.cfg").write_text("# a configuration not beside the rig\n")
    rig = box.case / "rig.toml"
    rig.write_text(
        'driver = "hardware"\n[micromanager]\nconfig = "../outside/MMConfig.cfg"\n'
        '[manipulator]\nkind = "micromanager"\nxy_stage = "XY"\nfocus = "Z"\n'
        "limits_um = { x = [0, 8000], y = [0, 8000], z = [0, 4800] }\n"
        '[cameras.top]\nkind = "micromanager"\ndevice = "Top"\n'
        '[cameras.side]\nkind = "micromanager"\ndevice = "Side"\n',
        encoding="utf-8",
    )
    act = lambda: run_traced("acquire", "--rig", rig, "--poses", 12, "--out", box.case / "run")  # noqa: E731
    refused_cleanly(box, act, "rig.toml", "micromanager.config", "beside the rig file")


def test_a_journal_image_outside_the_run_is_refused_on_resume(run, box):
    """A journal line may name only its pose's image in images/: not a file outside the run
    (a resume that checks its SHA-256 would tell whether a file of the user's holds given
    bytes)."""
    bait = box.outside / "bait.txt"

    def point_outside(records: list[dict[str, Any]]) -> None:
        records[2]["images"]["top"] |= {"file": "../../outside/bait.txt", "sha256": sha256(bait)}

    edit_journal(run, point_outside)
    refused_cleanly(box, resume(run), "journal.jsonl, line 3", "images.top.file", "inside it")


def test_a_journal_image_at_an_absolute_path_is_refused_by_measure(run, cameras, box):
    bait = box.outside / "bait.txt"
    edit_journal(run, lambda rs: rs[0]["images"]["side"].update(file=str(bait)))
    refused_cleanly(box, measure(run, cameras), "journal.jsonl, line 1", "images.side.file")


def test_a_journal_camera_named_as_a_path_is_refused(run, cameras, box):
    def rename(records: list[dict[str, Any]]) -> None:
        records[1]["images"]["../../outside/top"] = records[1]["images"]["top"]

    edit_journal(run, rename)
    refused_cleanly(box, measure(run, cameras), "journal.jsonl, line 2", "is not a name")


def test_a_run_json_camera_named_as_a_path_is_refused(run, cameras, box):
    edit_json(run / "run.json", lambda m: m.update(cameras=["../../outside/top", "side"]))
    refused_cleanly(box, measure(run, cameras), "run.json", "cameras", "is not a name")


def test_a_run_json_device_named_as_a_path_is_refused(run, box):
    edit_json(run / "run.json", lambda m: m.update(manipulator="../m1"))
    refused_cleanly(box, resume(run), "run.json", "manipulator", "is not a name")


def test_a_cameras_json_camera_named_as_a_path_is_refused(run, cameras, box):
    def rename(data: dict[str, Any]) -> None:
        data["cameras"]["../../outside/top"] = data["cameras"].pop("top")

    edit_json(cameras, rename)
    refused_cleanly(box, measure(run, cameras), "cameras.json", "cameras", "is not a name")


# --- 3. declared sizes and counts are bounded -----------------------------------------------
def test_a_journal_full_frame_beyond_reason_is_refused_before_allocating(run, cameras, box):
    """A stored region is pasted into a full frame of the size the journal declares: a
    million pixels square would be a terabyte."""
    edit_journal(run, lambda rs: rs[3]["images"]["top"].update(full_size_px=[10**6, 10**6]))
    refused_cleanly(box, measure(run, cameras), "journal.jsonl, line 4",
                    "images.top.full_size_px")  # fmt: skip


def test_a_journal_region_offset_outside_its_frame_is_refused(run, cameras, box):
    edit_journal(run, lambda rs: rs[0]["images"]["side"].update(offset_px=[-400, 10**9]))
    refused_cleanly(box, measure(run, cameras), "journal.jsonl, line 1",
                    "images.side.offset_px")  # fmt: skip


def test_a_run_json_frame_count_beyond_reason_is_refused_before_grabbing(run, box):
    """A resume grabs run.json's frames per pose and holds them: a million is refused."""
    edit_journal(run, lambda rs: rs.pop())  # a pose left to acquire
    edit_json(run / "run.json", lambda m: m.update(frames_per_pose=10**6))
    refused_cleanly(box, resume(run), "run.json", "frames_per_pose")


# --- 4. a resume never writes over a recorded image -----------------------------------------
def _kept_aside(run: Path) -> dict[str, str]:
    """The files a resume kept aside, by name: their SHA-256."""
    return {p.name: sha256(p) for p in (run / "images" / "_set_aside").rglob("*") if p.is_file()}


@pytest.mark.slow
def test_a_damaged_journal_line_keeps_its_images_aside(run, box):
    """Line 5 damaged in the middle and line 12 cut short: their poses are acquired again,
    and the images they had are moved aside (named in one line), never written over."""
    before = {p.name: sha256(p) for p in (run / "images").iterdir()}
    journal = run / "journal.jsonl"
    lines = journal.read_bytes().split(b"\n")
    lines[4] = lines[4][:30] + b"\x00{" + lines[4][32:]
    lines[11] = lines[11][: len(lines[11]) // 2]
    journal.write_bytes(b"\n".join(lines[:12]))
    outcome = kept_outside(box, resume(run))
    assert outcome.ran.returncode == 0, outcome.ran.stderr
    said = [line for line in outcome.ran.stdout.splitlines() if "_set_aside" in line]
    assert any("image file(s) of pose(s) 5, 12" in line for line in said), outcome.ran.stdout
    aside = _kept_aside(run)
    for name in ("top_0005.tiff", "side_0005.tiff", "top_0012.tiff", "side_0012.tiff"):
        assert aside[name] == before[name]
    assert [r["pose"] for r in journal_records(run)] == [*range(1, 5), *range(6, 12), 5, 12]


def test_images_a_stop_left_without_their_line_are_kept_aside(run, box):
    """A stop between a pose's images and its journal line: the images are kept aside
    before the pose is acquired again."""
    before = {p.name: sha256(p) for p in (run / "images").iterdir()}
    edit_journal(run, lambda rs: rs.pop())
    outcome = kept_outside(box, resume(run))
    assert outcome.ran.returncode == 0, outcome.ran.stderr
    assert "image file(s) of pose(s) 12" in outcome.ran.stdout
    aside = _kept_aside(run)
    assert aside["top_0012.tiff"] == before["top_0012.tiff"]
    assert aside["side_0012.tiff"] == before["side_0012.tiff"]
