"""check.json and the history of checks beside a calibration (``microcal check`` writes them).

- check.json (``microcal.check/1``): the verdict and its figures (keys in docs/formats.md).
- The history: ``<calibration>.checks.jsonl`` beside calibration.json, one JSON line per
  check of that file (identified by its SHA-256). The first check of a calibration that
  found it valid is the reference of the later ones (their residuals are compared with its
  residuals, pose by pose). A check whose offset lies more than ``history_sigma`` standard
  deviations from the offsets of the history (three or more checks) is flagged.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ..errors import FormatError
from .atomic import write_text_atomic
from .file_lock import locked_update
from .hashing import sha256_file
from .safe_open import read_regular_text

__all__ = [
    "CHECK_FORMAT",
    "append_history",
    "history_path",
    "of_device",
    "read_history",
]

CHECK_FORMAT = "microcal.check/1"


def history_path(calibration: str | os.PathLike[str]) -> Path:
    """``calibration.json`` -> ``calibration.checks.jsonl`` beside it."""
    p = Path(calibration)
    return p.with_name(f"{p.stem}.checks.jsonl")


def read_history(calibration: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The checks of this calibration file (its current SHA-256), oldest first.

    The history is read only from a regular file, never through a symbolic link (microcal
    writes it: :mod:`.safe_open`).
    """
    path = history_path(calibration)
    if not path.is_file():
        return []
    digest = sha256_file(calibration, link_ok=True)  # the calibration the user named
    out = []
    for k, line in enumerate(read_regular_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            raise FormatError(
                f"{path}: line {k} is not JSON; move the file away to start a new history"
            ) from None
        if isinstance(entry, dict) and entry.get("calibration_sha256") == digest:
            out.append(entry)
    return out


def of_device(history: list[dict[str, Any]], name: str, single: bool) -> list[dict[str, Any]]:
    """The history entries of device ``name``; entries that name none (made before devices
    were recorded) count only for a calibration of a single device."""
    return [h for h in history if h.get("manipulator", name if single else None) == name]


def append_history(path: Path, entry: dict[str, Any]) -> None:
    """Add one entry to a history file (rewritten whole, atomically, under its lock: two
    checks adding at once both land)."""
    line = json.dumps(entry, allow_nan=False) + "\n"
    with locked_update(path):
        old = read_regular_text(path) if path.is_file() else ""
        if old and not old.endswith("\n"):
            old += "\n"
        write_text_atomic(path, old + line)
