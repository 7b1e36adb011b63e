"""Hostile files: links, FIFOs and devices where microcal reads or writes a file, image bombs,
and messages that would quote a file a link points to.

Every case builds its inputs under ``box.case`` (bait under ``box.outside``) and checks the
promise of :mod:`support.hostile`: a one-line refusal (or the right outcome), nothing outside
changed, bounded memory, no wait for ever.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
import struct
import threading
import tracemalloc
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import tifffile

from microcal.errors import FormatError
from microcal.formats.atomic import write_text_atomic
from microcal.formats.check_file import append_history, read_history
from microcal.formats.images import read_frames
from support.hostile import MEMORY_BOUND_BYTES, Outcome, Sandbox, refused_cleanly, run_traced
from support.runs import write_true_cameras

SECRET = "root:$6$SECRETSALT$c2VjcmV0IGhhc2ggdGhhdCBtdXN0IG5vdCBsZWFr:19000:0:99999:7:::"
#: The declared size of an image bomb, px.
BOMB_PX = 40000


# --- building inputs -------------------------------------------------------------------------
@pytest.fixture
def box(tmp_path: Path) -> Sandbox:
    return Sandbox.make(tmp_path)


@pytest.fixture
def in_process(monkeypatch: pytest.MonkeyPatch) -> None:
    """Measure in this process (no forked workers), so its allocations are traced."""
    monkeypatch.setattr("microcal._parallel.can_fork", lambda: False)


def _tiff(path: Path, shape: tuple[int, ...] = (16, 16)) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    tifffile.imwrite(path, np.full(shape, 100, np.uint8), photometric="minisblack")
    return path


def _run(box: Sandbox, cameras: tuple[str, ...] = ("top", "side")) -> Path:
    """A run of one pose without run.json or journal: commands.csv and one image per camera."""
    run = box.case / "run"
    (run / "images").mkdir(parents=True)
    (run / "commands.csv").write_text("pose,dx_um,dy_um,dz_um\n1,100,200,300\n")
    for cam in cameras:
        _tiff(run / "images" / f"{cam}_0001.tiff")
    return run


def _measure(box: Sandbox, run: Path) -> Callable[[], Outcome]:
    cameras = box.case / "cameras.json"
    if not cameras.exists():
        write_true_cameras(cameras)
    return lambda: run_traced("measure", run, "--cameras", cameras)


def _bait_link(path: Path, box: Sandbox, name: str = "bait.txt") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.symlink_to(box.outside / name)
    return path


def _fifo(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    return path


@contextlib.contextmanager
def no_wait_on(fifo: Path, after_s: float = 5.0) -> Iterator[None]:
    """Fail, rather than hang, when something opens ``fifo`` and waits on it: after
    ``after_s`` a writer opens and closes it, so a blocked reader sees its end."""
    fired, stop = threading.Event(), threading.Event()

    def unblock() -> None:
        while not stop.wait(after_s):
            with contextlib.suppress(OSError):
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
                fired.set()

    watcher = threading.Thread(target=unblock, daemon=True)
    watcher.start()
    try:
        yield
    finally:
        stop.set()
        watcher.join()
    assert not fired.is_set(), f"{fifo}: microcal opened the FIFO and waited on it"


def _png_bomb(path: Path, size_px: int = BOMB_PX) -> Path:
    """A small PNG whose header declares size_px x size_px grey pixels (its data: a few rows)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    ihdr = struct.pack(">IIBBBBB", size_px, size_px, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\0" * (size_px + 1) * 4, 9)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")
    )
    return path


def _tiff_bomb(path: Path, size_px: int = BOMB_PX, tile_px: int = 1024) -> Path:
    """A small TIFF that declares size_px x size_px grey pixels: every tile's offset points
    to one deflated tile of zeros (about 14 KB for 40000 x 40000 px)."""
    tile = zlib.compress(b"\0" * tile_px * tile_px, 9)
    n = (-(-size_px // tile_px)) ** 2  # tiles across, squared
    tags = [  # (tag, type, count, value): 3 SHORT, 4 LONG
        (256, 4, 1, size_px), (257, 4, 1, size_px), (258, 3, 1, 8), (259, 3, 1, 8),
        (262, 3, 1, 1), (277, 3, 1, 1), (322, 3, 1, tile_px), (323, 3, 1, tile_px),
        (324, 4, n, 0), (325, 4, n, 0),
    ]  # fmt: skip
    offsets_at = 8 + 2 + 12 * len(tags) + 4
    counts_at = offsets_at + 4 * n
    tile_at = counts_at + 4 * n

    def entry(tag: int, kind: int, count: int, value: int) -> bytes:
        if tag in (324, 325):
            return struct.pack("<HHII", tag, kind, count, offsets_at if tag == 324 else counts_at)
        if kind == 4:
            return struct.pack("<HHII", tag, kind, count, value)
        return struct.pack("<HHIHH", tag, kind, count, value, 0)

    ifd = struct.pack("<H", len(tags)) + b"".join(entry(*t) for t in tags) + b"\0\0\0\0"
    arrays = struct.pack(f"<{n}I", *[tile_at] * n) + struct.pack(f"<{n}I", *[len(tile)] * n)
    path.write_bytes(b"II*\0" + struct.pack("<I", 8) + ifd + arrays + tile)
    return path


# --- 1. links and special files a run names are not followed --------------------------------
def test_measure_refuses_a_journal_that_is_a_link(box: Sandbox):
    run = _run(box)
    _bait_link(run / "journal.jsonl", box)
    refused_cleanly(box, _measure(box, run), "journal.jsonl", "symbolic link", "regular file")


def test_measure_refuses_a_run_json_that_is_a_link(box: Sandbox):
    run = _run(box)
    _bait_link(run / "run.json", box)
    refused_cleanly(box, _measure(box, run), "run.json", "symbolic link", "regular file")


def test_measure_does_not_wait_on_a_run_json_that_is_a_fifo(box: Sandbox):
    run = _run(box)
    fifo = _fifo(run / "run.json")
    with no_wait_on(fifo):
        refused_cleanly(box, _measure(box, run), "run.json", "FIFO", "regular file")


def test_measure_refuses_commands_that_are_a_link(box: Sandbox):
    run = _run(box)
    (box.outside / "commands.csv").write_text("pose,dx_um,dy_um,dz_um\n1,1,2,3\n")
    (run / "commands.csv").unlink()
    _bait_link(run / "commands.csv", box, "commands.csv")
    refused_cleanly(box, _measure(box, run), "commands.csv", "symbolic link")


def test_measure_does_not_read_an_image_through_a_link(box: Sandbox, in_process: None):
    run = _run(box)
    _tiff(box.outside / "elsewhere.tiff")
    (run / "images" / "top_0001.tiff").unlink()
    _bait_link(run / "images" / "top_0001.tiff", box, "elsewhere.tiff")
    refused_cleanly(box, _measure(box, run), "top_0001.tiff", "symbolic link")


def test_measure_does_not_wait_on_measurements_that_are_a_fifo(box: Sandbox):
    run = _run(box)
    fifo = _fifo(run / "measurements.csv")
    with no_wait_on(fifo):
        refused_cleanly(box, _measure(box, run), "measurements.csv", "FIFO")


def test_the_run_lock_is_never_followed_through_a_link(box: Sandbox):
    run = _run(box)
    _bait_link(run / ".microcal.lock", box)
    refused_cleanly(box, _measure(box, run), ".microcal.lock", "symbolic link")


def test_the_run_lock_is_not_a_device(box: Sandbox):
    run = _run(box)
    (run / ".microcal.lock").symlink_to("/dev/null")
    refused_cleanly(box, _measure(box, run), ".microcal.lock", "symbolic link")


def test_the_history_of_checks_is_not_read_through_a_link(box: Sandbox):
    calibration = box.case / "calibration.json"
    calibration.write_text("{}\n")
    (box.outside / "bait.txt").write_text(SECRET + "\n")
    _bait_link(box.case / "calibration.checks.jsonl", box)
    with pytest.raises(FormatError, match="symbolic link") as err:
        read_history(calibration)
    assert "SECRET" not in str(err.value)


def test_the_history_of_checks_is_not_appended_through_a_link(box: Sandbox):
    history = _bait_link(box.case / "calibration.checks.jsonl", box)
    before = (box.outside / "bait.txt").read_bytes()
    with pytest.raises(FormatError, match="symbolic link"):
        append_history(history, {"offset_um": [0.0, 0.0, 0.0]})
    assert history.is_symlink()
    assert (box.outside / "bait.txt").read_bytes() == before
    assert not list(box.outside.glob(".*.lock"))


# --- 2. a message never quotes a file a link points to --------------------------------------
def test_a_design_link_to_a_secret_is_not_quoted(box: Sandbox):
    (box.outside / "bait.txt").write_text(SECRET + "\n")
    design = _bait_link(box.case / "design.csv", box)
    line = refused_cleanly(box, lambda: run_traced(
        "acquire", "--rig", "sim", "--design", design, "--out", box.case / "run", "--dry-run",
        "--frames", "1", "--settle", "fixed:0"), "design.csv", "missing column")  # fmt: skip
    assert "SECRET" not in line
    assert "$6$" not in line


def test_a_cell_is_quoted_short_and_escaped(box: Sandbox):
    design = box.case / "design.csv"
    cell = "\x1b[2J" + "A" * 500
    design.write_text(f"dx_um,dy_um,dz_um\n{cell},1,2\n")
    line = refused_cleanly(box, lambda: run_traced(
        "acquire", "--rig", "sim", "--design", design, "--out", box.case / "run", "--dry-run",
        "--frames", "1", "--settle", "fixed:0"), "design.csv", "dx_um", "not a number")  # fmt: skip
    assert "\x1b" not in line
    assert "A" * 60 not in line


# --- 3. images: the header first, then the pixels -------------------------------------------
@pytest.mark.parametrize("make", [_tiff_bomb, _png_bomb], ids=["tiff", "png"])
def test_an_image_bomb_is_refused_before_decoding(box: Sandbox, make, in_process: None):
    run = _run(box)
    suffix = ".tiff" if make is _tiff_bomb else ".png"
    for cam in ("top", "side"):
        (run / "images" / f"{cam}_0001.tiff").unlink()
        make(run / "images" / f"{cam}_0001{suffix}")
    line = refused_cleanly(box, _measure(box, run), f"declares frames of {BOMB_PX} x {BOMB_PX}")
    assert "no pose measured" in line


@pytest.mark.parametrize("make", [_tiff_bomb, _png_bomb], ids=["tiff", "png"])
def test_an_image_bomb_is_refused_by_the_absolute_bound(tmp_path: Path, make):
    bomb = make(tmp_path / ("bomb.tiff" if make is _tiff_bomb else "bomb.png"))
    tracemalloc.start()
    try:
        with pytest.raises(FormatError, match=f"declares {BOMB_PX} x {BOMB_PX} px"):
            read_frames(bomb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_BOUND_BYTES


def test_a_journal_that_declares_huge_frames_is_refused(box: Sandbox, in_process: None):
    run = _run(box)
    lines = []
    for cam in ("top", "side"):
        image = run / "images" / f"{cam}_0001.tiff"
        entry = {"file": f"images/{cam}_0001.tiff",
                 "sha256": hashlib.sha256(image.read_bytes()).hexdigest(), "frames": 1,
                 "offset_px": [0, 0], "full_size_px": [BOMB_PX, BOMB_PX]}  # fmt: skip
        lines.append((cam, entry))
    record = {"pose": 1, "status": "ok", "images": dict(lines)}
    (run / "journal.jsonl").write_text(json.dumps(record) + "\n")
    refused_cleanly(box, _measure(box, run), "journal.jsonl", f"{BOMB_PX} x {BOMB_PX}")


# --- 4. the atomic writer: permissions kept, links and special files never replaced ---------
def test_a_replaced_file_keeps_its_permissions(box: Sandbox):
    path = box.case / "calibration.json"
    path.write_text("{}\n")
    path.chmod(0o600)
    write_text_atomic(path, '{"a": 1}\n')
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    path.chmod(0o640)
    write_text_atomic(path, '{"a": 2}\n')
    assert stat.S_IMODE(path.stat().st_mode) == 0o640


@pytest.mark.parametrize("kind", ["link", "fifo"])
def test_the_atomic_writer_never_replaces_a_link_or_a_fifo(box: Sandbox, kind: str):
    path = box.case / "results.json"
    _bait_link(path, box) if kind == "link" else _fifo(path)
    with pytest.raises(FormatError, match="not a regular file"):
        write_text_atomic(path, "{}\n")
    assert path.is_symlink() if kind == "link" else stat.S_ISFIFO(path.lstat().st_mode)
    assert not list(box.case.glob(".*.tmp"))


# --- 5. --out is a regular file or a new path, refused in one line before any work -------------
def _outputs(box: Sandbox, out: Path) -> list[list[object]]:
    """One command line per output option, ``out`` in its place."""
    run = box.case / "run-report"
    if not run.exists():
        run.mkdir()
        (run / "commands.csv").write_text("pose,dx_um,dy_um,dz_um\n1,1,2,3\n")
    cal = box.case / "calibration.json"
    return [
        ["fit", box.case / "measurements.csv", "--out", out],
        ["fit", box.case / "measurements.csv", "--out", box.case / "new.json", "--mat", out],
        ["evaluate", "--calibration", cal, "--out", out],
        ["report", run, "--out", out],
        ["check", "--calibration", cal, "--out", out],
        ["check", "--calibration", cal, "--out", box.case / "check.json", "--update", out],
        ["stereo-calibrate", "--target", "chessboard:7x5:30000", "--images",
         f"left={box.case}/none_*.png", "--out", out],
    ]  # fmt: skip


_COMMANDS = ["fit", "fit-mat", "evaluate", "report", "check", "check-update", "stereo"]


@pytest.mark.parametrize("k", range(len(_COMMANDS)), ids=_COMMANDS)
def test_an_output_that_is_a_fifo_is_refused_without_waiting(box: Sandbox, k: int):
    fifo = _fifo(box.case / "out.json")
    argv = _outputs(box, fifo)[k]
    with no_wait_on(fifo):
        refused_cleanly(box, lambda: run_traced(*argv), "out.json", "FIFO", "regular file")


@pytest.mark.parametrize("k", range(len(_COMMANDS)), ids=_COMMANDS)
def test_an_output_that_is_a_device_is_refused(box: Sandbox, k: int):
    argv = _outputs(box, Path("/dev/null"))[k]
    refused_cleanly(box, lambda: run_traced(*argv), "/dev/null", "a device", "regular file")


@pytest.mark.parametrize("k", range(len(_COMMANDS)), ids=_COMMANDS)
def test_an_output_that_is_a_link_is_refused(box: Sandbox, k: int):
    link = _bait_link(box.case / "out.json", box)
    argv = _outputs(box, link)[k]
    refused_cleanly(box, lambda: run_traced(*argv), "out.json", "symbolic link")
    assert link.is_symlink()


def test_twin_refuses_a_rig_out_that_is_a_device(box: Sandbox):
    refused_cleanly(box, lambda: run_traced("twin", "--rig-out", "/dev/null"), "/dev/null",
                    "a device")  # fmt: skip
