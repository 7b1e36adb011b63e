"""``measurements.csv``: measured end-effector positions of an acquisition run.

One row per pose, a header naming units. Columns (others are kept and ignored here):

| column | meaning |
| --- | --- |
| `pose` | pose number, 1-based as in the image names |
| `status` | `ok`, or `failed` (with `reason`) |
| `dx_um`, `dy_um`, `dz_um` | joint commands, µm |
| `x_um`, `y_um`, `z_um` | measured position of the end-effector in {G}, µm |
| `sx_um`, `sy_um`, `sz_um` | (optional) standard deviation of the measured position, µm |
| `temperature_c` | (optional) ambient temperature, °C |
| `reason` | (optional) why a pose failed |
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError
from .atomic import write_text_atomic

__all__ = [
    "JOINT_COLUMNS",
    "POSITION_COLUMNS",
    "Measurements",
    "read_measurements",
    "write_measurements",
]

JOINT_COLUMNS = ("dx_um", "dy_um", "dz_um")
POSITION_COLUMNS = ("x_um", "y_um", "z_um")
STD_COLUMNS = ("sx_um", "sy_um", "sz_um")
REQUIRED = ("pose", "status", *JOINT_COLUMNS, *POSITION_COLUMNS)


@dataclass(frozen=True)
class Measurements:
    """The usable (status ok) rows of a measurements file, in file order."""

    pose: np.ndarray  # (N,) int
    d_um: FloatArray  # (N, 3) joint commands
    p_um: FloatArray  # (N, 3) measured positions in {G}
    std_um: FloatArray | None  # (N, 3)
    temperature_c: FloatArray | None  # (N,)
    n_failed: int
    failed_reasons: dict[int, str]


def read_measurements(path: str | os.PathLike[str]) -> Measurements:
    """Read ``measurements.csv``; rows with a status other than ``ok`` are counted, not used.

    Raises
    ------
    FormatError
        Missing file or columns, values that are not numbers, duplicate poses.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FormatError(f"{p}: no such file (run 'microcal measure' first)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(f"{p}: cannot be read as text ({exc})") from None
    reader = csv.DictReader(io.StringIO(text))
    header = reader.fieldnames or []
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise FormatError(f"{p}: missing column(s) {missing}; expected at least {list(REQUIRED)}")
    has_std = all(c in header for c in STD_COLUMNS)
    has_temp = "temperature_c" in header
    rows = []
    seen: set[int] = set()
    n_failed = 0
    reasons: dict[int, str] = {}
    for line, row in enumerate(reader, start=2):
        try:
            pose = int(row["pose"])
        except (TypeError, ValueError):
            raise FormatError(f"{p}, line {line}: pose {row['pose']!r} is not an integer") from None
        if pose in seen:
            raise FormatError(f"{p}, line {line}: pose {pose} appears twice")
        seen.add(pose)
        if (row["status"] or "").strip() != "ok":
            n_failed += 1
            reasons[pose] = (row.get("reason") or row["status"] or "").strip()
            continue
        cols = [*JOINT_COLUMNS, *POSITION_COLUMNS]
        cols += list(STD_COLUMNS) if has_std else []
        cols += ["temperature_c"] if has_temp else []
        try:
            values = [float(row[c]) for c in cols]
        except (TypeError, ValueError):
            bad = [c for c in cols if not _is_number(row[c])]
            raise FormatError(
                f"{p}, line {line}: {bad[0]} = {row[bad[0]]!r} is not a number"
            ) from None
        if not np.all(np.isfinite(values)):
            raise FormatError(f"{p}, line {line}: non-finite value in a status-ok row")
        rows.append([pose, *values])
    if not rows:
        raise FormatError(f"{p}: no row has status 'ok' ({n_failed} failed)")
    a = np.asarray(rows, dtype=np.float64)
    col = 7
    std = a[:, col : col + 3] if has_std else None
    col += 3 if has_std else 0
    temp = a[:, col] if has_temp else None
    return Measurements(a[:, 0].astype(int), a[:, 1:4], a[:, 4:7], std, temp, n_failed, reasons)


def _is_number(text: str | None) -> bool:
    try:
        float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return True


def write_measurements(
    path: str | os.PathLike[str],
    d_um: FloatArray,
    p_um: FloatArray,
    *,
    std_um: FloatArray | None = None,
    temperature_c: FloatArray | None = None,
    status: list[str] | None = None,
    reason: list[str] | None = None,
) -> Path:
    """Write a measurements file atomically (poses numbered from 1)."""
    n = d_um.shape[0]
    header = ["pose", "status", *JOINT_COLUMNS, *POSITION_COLUMNS]
    header += list(STD_COLUMNS) if std_um is not None else []
    header += ["temperature_c"] if temperature_c is not None else []
    header += ["reason"]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for i in range(n):
        row: list[object] = [i + 1, status[i] if status else "ok"]
        row += [f"{v:.6f}" for v in d_um[i]] + [f"{v:.6f}" for v in p_um[i]]
        row += [f"{v:.6f}" for v in std_um[i]] if std_um is not None else []
        row += [f"{temperature_c[i]:.4f}"] if temperature_c is not None else []
        row += [reason[i] if reason else ""]
        w.writerow(row)
    return write_text_atomic(path, out.getvalue())
