"""What tests of run directories share: the simulator's true cameras as a cameras.json, the
files of a run with their digests, its journal, and the one-line refusal of a command."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Protocol

from microcal import sim
from microcal.formats.cameras_file import write_cameras


class Ran(Protocol):
    """What a finished command leaves: its exit code and both outputs."""

    returncode: int
    stdout: str
    stderr: str


def write_true_cameras(path: Path, seed: int = 0) -> Path:
    """The thesis preset's true cameras (seed ``seed``) as a cameras.json at ``path``."""
    plat = sim.platform("thesis", seed=seed)
    cams = {"format": "microcal.cameras/1", "cameras": {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()} for n, m in plat.camera_models.items()}}  # fmt: skip
    return write_cameras(path, cams)


def file_hashes(root: Path) -> dict[str, str]:
    """SHA-256 of every file under ``root``, by its path relative to it."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def journal_records(run: Path) -> list[dict[str, Any]]:
    """The run's journal lines, parsed (blank lines skipped)."""
    return [json.loads(x) for x in (run / "journal.jsonl").read_text().splitlines() if x.strip()]


def fails_cleanly(out: Ran, *needles: str) -> str:
    """Exit code 2 and one ``microcal: error:`` line on stderr holding every needle."""
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("microcal: error: ")
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]
