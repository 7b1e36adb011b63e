"""The run directory of an acquisition: commands, images, and what is derived from them.

```
RUN_DIR/run.json              manifest (target spec, cameras, rig, software, created)
RUN_DIR/commands.csv          pose, dx_um, dy_um, dz_um
RUN_DIR/images/top_0001.tiff  one file per camera and pose (several pages = several frames)
RUN_DIR/measurements.csv      written by `microcal measure`
```
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError
from .atomic import write_text_atomic

__all__ = ["find_image", "read_commands", "read_manifest", "write_commands"]

IMAGE_SUFFIXES = (".tiff", ".tif", ".png", ".jpg", ".jpeg")


def read_commands(run_dir: str | os.PathLike[str]) -> tuple[list[int], FloatArray]:
    """Pose numbers and joint commands (N, 3) µm from ``commands.csv``."""
    path = Path(run_dir) / "commands.csv"
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FormatError(f"{path}: no such file (is {run_dir} a run directory?)") from None
    reader = csv.DictReader(io.StringIO(text))
    need = ["pose", "dx_um", "dy_um", "dz_um"]
    missing = [c for c in need if c not in (reader.fieldnames or [])]
    if missing:
        raise FormatError(f"{path}: missing column(s) {missing}; expected {need}")
    poses, rows = [], []
    for line, row in enumerate(reader, start=2):
        try:
            poses.append(int(row["pose"]))
            rows.append([float(row[c]) for c in need[1:]])
        except (TypeError, ValueError):
            raise FormatError(
                f"{path}, line {line}: expected a pose number and three numbers"
            ) from None
    if not rows:
        raise FormatError(f"{path}: no commands")
    if len(set(poses)) != len(poses):
        raise FormatError(f"{path}: a pose number appears twice")
    d = np.array(rows)
    if not np.all(np.isfinite(d)):
        raise FormatError(f"{path}: non-finite command")
    return poses, d


def write_commands(run_dir: str | os.PathLike[str], d_um: FloatArray) -> Path:
    """Write ``commands.csv`` (poses numbered from 1) atomically."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["pose", "dx_um", "dy_um", "dz_um"])
    for i, row in enumerate(np.asarray(d_um, dtype=np.float64), start=1):
        w.writerow([i, *(f"{v:.4f}" for v in row)])
    return write_text_atomic(Path(run_dir) / "commands.csv", out.getvalue())


def find_image(run_dir: str | os.PathLike[str], camera: str, pose: int) -> Path | None:
    """The image file of a camera at a pose (``images/CAMERA_0001.tiff``), if present."""
    stem = Path(run_dir) / "images" / f"{camera}_{pose:04d}"
    for suffix in IMAGE_SUFFIXES:
        candidate = stem.with_suffix(suffix)
        if candidate.is_file():
            return candidate
    return None


def read_manifest(run_dir: str | os.PathLike[str]) -> dict[str, object]:
    """``run.json`` as a dict, or {} when the run has none."""
    path = Path(run_dir) / "run.json"
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise FormatError(f"{path}: not a JSON file ({exc})") from None
    if not isinstance(data, dict):
        raise FormatError(f"{path}: expected a JSON object")
    return data
