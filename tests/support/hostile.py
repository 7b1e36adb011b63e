"""The promise every hostile input must keep, checked the same way for every case.

A hostile case builds its inputs from scratch in ``<tmp>/case`` (a run directory, a
calibration, a rig file...), may plant bait in ``<tmp>/outside`` (files a symbolic link points
to, a directory a ``../`` name would reach), runs one command in this process and hands the
outcome to :func:`refused_cleanly` or :func:`kept_outside`, which assert:

- nothing outside the case's folder changed (every file under ``outside`` keeps its bytes,
  its mode and its modification time; nothing new appears there);
- the answer is one clear line (exit code 2, one ``microcal: error:`` line, no traceback);
- Python's peak allocation during the command stayed under a bound (numpy's arrays count:
  they are traced).
"""

from __future__ import annotations

import os
import stat
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .cli import Ran, invoke_microcal

#: Peak allocation a refusal may reach, bytes (the issue's bound for image bombs is 500 MB).
MEMORY_BOUND_BYTES = 500 * 1024 * 1024


@dataclass(frozen=True)
class Sandbox:
    """A case's own folder and the folder outside it that the case must leave alone."""

    case: Path
    outside: Path

    @classmethod
    def make(cls, root: Path) -> Sandbox:
        """``root/case`` (the case's inputs) and ``root/outside`` with one bait file."""
        case, outside = root / "case", root / "outside"
        case.mkdir(parents=True)
        outside.mkdir(parents=True)
        (outside / "bait.txt").write_text("a file that is not microcal's\n")
        return cls(case, outside)


def snapshot(root: Path) -> dict[str, tuple[str, int, int, bytes]]:
    """Every entry under ``root`` (links not followed): kind, mode, mtime and bytes."""
    seen: dict[str, tuple[str, int, int, bytes]] = {}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st = p.lstat()
            if stat.S_ISREG(st.st_mode):
                kind, data = "file", p.read_bytes()
            elif stat.S_ISLNK(st.st_mode):
                kind, data = "link", os.readlink(p).encode()
            elif stat.S_ISDIR(st.st_mode):
                kind, data = "dir", b""
            else:
                kind, data = "special", b""
            seen[str(p.relative_to(root))] = (kind, st.st_mode, st.st_mtime_ns, data)
    return seen


@dataclass(frozen=True)
class Outcome:
    """What one hostile command left: its outputs and Python's peak allocation, bytes."""

    ran: Ran
    peak_bytes: int


def run_traced(*args: object, cwd: Path | None = None) -> Outcome:
    """Run ``microcal ARGS`` in this process with allocations traced."""
    tracemalloc.start()
    try:
        ran = invoke_microcal(*args, cwd=cwd)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return Outcome(ran, peak)


def kept_outside(box: Sandbox, act: Callable[[], Outcome]) -> Outcome:
    """Run ``act`` and assert nothing under ``box.outside`` changed and memory stayed bounded."""
    before = snapshot(box.outside)
    outcome = act()
    after = snapshot(box.outside)
    assert after == before, (
        f"changed outside the case: {sorted(set(after.items()) ^ set(before.items()))[:3]}"
    )
    assert outcome.peak_bytes < MEMORY_BOUND_BYTES, f"peak {outcome.peak_bytes / 2**20:.0f} MiB"
    text = outcome.ran.stdout + outcome.ran.stderr
    assert "Traceback" not in text, text
    return outcome


def refused_cleanly(box: Sandbox, act: Callable[[], Outcome], *needles: str) -> str:
    """Run ``act`` under :func:`kept_outside` and assert one clear refusal naming ``needles``.

    Returns the refusal's line.
    """
    outcome = kept_outside(box, act)
    ran = outcome.ran
    lines = [line for line in ran.stderr.splitlines() if line.strip()]
    assert ran.returncode == 2, (ran.returncode, ran.stdout, ran.stderr)
    assert len(lines) == 1, ran.stderr
    assert lines[0].startswith("microcal: error: "), ran.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]
