"""``measurements.csv``: measured end-effector positions of an acquisition run.

One row per pose, a header naming units. Columns (others are kept and ignored here):

| column | meaning |
| --- | --- |
| `pose` | pose number, 1-based as in the image names |
| `status` | `ok`, or `failed` (with `reason`) |
| `dx_um`, `dy_um`, `dz_um` | joint commands, µm |
| `x_um`, `y_um`, `z_um` | measured position of the end-effector in {G}, µm |
| `sx_um`, `sy_um`, `sz_um` | (optional) standard deviation of the measured position, µm |
| `cxx_um2` ... `czz_um2` | (optional) its covariance's six entries `xx, xy, xz, yy, yz, zz`, µm² |
| `temperature_c` | (optional) ambient temperature, °C |
| `reason` | (optional) why a pose failed |

Extra inputs of a model (:mod:`microcal.kinematics.extra_inputs`) each have a column named
by the registry (temperature: `temperature_c`); an empty cell or `nan` means not recorded.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._validation import FloatArray, excerpt
from ..errors import FormatError, InputError
from ..kinematics.extra_inputs import EXTRA_INPUTS, expand_names, extra_input
from .atomic import write_text_atomic
from .safe_open import read_regular_text

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
#: The covariance's upper triangle, row by row: (row, column) of each column.
COV_COLUMNS = {"cxx_um2": (0, 0), "cxy_um2": (0, 1), "cxz_um2": (0, 2), "cyy_um2": (1, 1),
               "cyz_um2": (1, 2), "czz_um2": (2, 2)}  # fmt: skip
REQUIRED = ("pose", "status", *JOINT_COLUMNS, *POSITION_COLUMNS)


@dataclass(frozen=True)
class Measurements:
    """The usable (status ok) rows of a measurements file, in file order."""

    pose: np.ndarray  # (N,) int
    d_um: FloatArray  # (N, 3) joint commands
    p_um: FloatArray  # (N, 3) measured positions in {G}
    std_um: FloatArray | None  # (N, 3)
    n_failed: int
    failed_reasons: dict[int, str]
    extra: dict[str, FloatArray] = field(default_factory=dict)  # registry name -> (N,)

    @property
    def temperature_c(self) -> FloatArray | None:
        """(N,) the ambient temperature, °C, if recorded (the registry's ``temperature``)."""
        return self.extra.get("temperature")

    def extra_inputs(self, names: list[str], path: str | os.PathLike[str]) -> dict[str, FloatArray]:
        """Values of extra inputs by registry name (a group such as ``approach`` stands for
        its members), each recorded at every pose used.

        Raises
        ------
        InputError
            An input without its column, or with poses where it was not recorded.
        """
        out: dict[str, FloatArray] = {}
        for name in expand_names(names):
            entry = extra_input(name)
            values = self.extra.get(name)
            if values is None:
                raise InputError(f"--{name}: {path} has no {entry.column!r} column")
            missing = self.pose[~np.isfinite(values)]
            if missing.size:
                raise InputError(
                    f"--{name}: {path} has no {entry.column} at {missing.size} pose(s) "
                    f"(first: pose {int(missing[0])}); the rig recorded none there"
                )
            out[name] = values
        return out


def read_measurements(
    path: str | os.PathLike[str], min_poses: int = 1, *, link_ok: bool = True
) -> Measurements:
    """Read ``measurements.csv``; rows with a status other than ``ok`` are counted, not used.

    ``link_ok``: ``path`` may be a symbolic link to the file (one the user named); False for
    the file of a run directory (:mod:`.safe_open`).

    Raises
    ------
    FormatError
        Missing file or columns, values that are not numbers, duplicate poses, fewer
        measured poses than ``min_poses``.
    """
    p = Path(path)
    try:
        text = read_regular_text(p, link_ok=link_ok)
    except FileNotFoundError:
        raise FormatError(f"{p}: no such file (run 'microcal measure' first)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(f"{p}: cannot be read as text ({exc})") from None
    try:
        meas = _parse_measurements(p, text)
    except csv.Error as exc:
        raise FormatError(f"{p}: not a CSV file microcal can read ({exc})") from None
    if meas.pose.size < min_poses:
        raise FormatError(
            f"{p}: {meas.pose.size} measured poses ({meas.n_failed} failed); identifying a "
            f"model needs at least {min_poses}"
        )
    return meas


def _parse_measurements(p: Path, text: str) -> Measurements:
    reader = csv.DictReader(io.StringIO(text.removeprefix("\ufeff")))
    header = reader.fieldnames or []
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise FormatError(f"{p}: missing column(s) {missing}; expected at least {list(REQUIRED)}")
    has_std = all(c in header for c in STD_COLUMNS)
    extra_names = [n for n, e in EXTRA_INPUTS.items() if e.column in header]
    extra_rows: list[list[float]] = []
    rows = []
    seen: set[int] = set()
    n_failed = 0
    reasons: dict[int, str] = {}
    for line, row in enumerate(reader, start=2):
        try:
            pose = int(row["pose"])
        except (TypeError, ValueError):
            pose_cell = excerpt(row["pose"])
            raise FormatError(f"{p}, line {line}: pose {pose_cell} is not an integer") from None
        if not 0 <= pose < 10**9:
            raise FormatError(f"{p}, line {line}: pose {pose} is not a pose number (0 to 10^9)")
        if pose in seen:
            raise FormatError(f"{p}, line {line}: pose {pose} appears twice")
        seen.add(pose)
        if (row["status"] or "").strip() != "ok":
            n_failed += 1
            reasons[pose] = (row.get("reason") or row["status"] or "").strip()
            continue
        cols = [*JOINT_COLUMNS, *POSITION_COLUMNS]
        cols += list(STD_COLUMNS) if has_std else []
        try:
            values = [float(row[c]) for c in cols]
        except (TypeError, ValueError):
            bad = [c for c in cols if not _is_number(row[c])]
            raise FormatError(
                f"{p}, line {line}: {bad[0]} = {excerpt(row[bad[0]])} is not a number"
            ) from None
        if not np.all(np.isfinite(values)):
            column = cols[int(np.flatnonzero(~np.isfinite(values))[0])]
            raise FormatError(
                f"{p}, line {line}: {column} = {excerpt(row[column])} in a status-ok row "
                f"(expected a finite number)"
            )
        negative = [c for c, v in zip(cols, values, strict=True) if c in STD_COLUMNS and v < 0]
        if negative:
            raise FormatError(
                f"{p}, line {line}: {negative[0]} = {row[negative[0]]!r} is a standard deviation "
                f"below zero; {', '.join(STD_COLUMNS)} must be >= 0 (measure the run again)"
            )
        rows.append([pose, *values])
        extra_rows.append([_extra_value(p, line, row, EXTRA_INPUTS[n].column) for n in extra_names])
    if not rows:
        raise FormatError(f"{p}: no row has status 'ok' ({n_failed} failed)")
    a = np.asarray(rows, dtype=np.float64)
    col = 7
    std = a[:, col : col + 3] if has_std else None
    ex = np.asarray(extra_rows, dtype=np.float64).reshape(len(rows), len(extra_names))
    extra = {n: ex[:, k] for k, n in enumerate(extra_names)}
    pose_ids = a[:, 0].astype(int)
    return Measurements(pose_ids, a[:, 1:4], a[:, 4:7], std, n_failed, reasons, extra)


def _extra_value(path: Path, line: int, row: dict[str, str], column: str) -> float:
    """An extra input's cell: a number, or NaN where it was not recorded (empty, ``nan``)."""
    text = (row.get(column) or "").strip()
    if text == "" or text.lower() == "nan":
        return float("nan")
    if not _is_number(text) or not np.isfinite(float(text)):
        raise FormatError(f"{path}, line {line}: {column} = {excerpt(text)} is not a number")
    return float(text)


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
    extra: dict[str, FloatArray] | None = None,
    pose: list[int] | None = None,
    cov_um2: FloatArray | None = None,
) -> Path:
    """Write a measurements file atomically.

    Parameters
    ----------
    cov_um2 : (N, 3, 3) float, optional
        The measured positions' covariances (:data:`COV_COLUMNS`); NaN: a failed pose.
    extra : dict of name -> (N,) float, optional
        Extra inputs by registry name, each in its column (NaN: not recorded);
        ``temperature_c`` is the same as ``extra={"temperature": ...}``.
    pose : list of N int, optional
        The pose numbers (default 1 to N).
    """
    n = d_um.shape[0]
    extras = dict(extra or {})
    if temperature_c is not None:
        extras["temperature"] = temperature_c
    columns = [(extra_input(name).column, np.asarray(v, float)) for name, v in extras.items()]
    header = ["pose", "status", *JOINT_COLUMNS, *POSITION_COLUMNS]
    header += list(STD_COLUMNS) if std_um is not None else []
    header += list(COV_COLUMNS) if cov_um2 is not None else []
    header += [c for c, _ in columns]
    header += ["reason"]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for i in range(n):
        row: list[object] = [pose[i] if pose else i + 1, status[i] if status else "ok"]
        row += [f"{v:.6f}" for v in d_um[i]] + [f"{v:.6f}" for v in p_um[i]]
        row += [f"{v:.6f}" for v in std_um[i]] if std_um is not None else []
        if cov_um2 is not None:
            row += [f"{cov_um2[i][rc]:.6g}" for rc in COV_COLUMNS.values()]
        row += ["" if not np.isfinite(v[i]) else f"{v[i]:.4f}" for _, v in columns]
        row += [reason[i] if reason else ""]
        w.writerow(row)
    return write_text_atomic(path, out.getvalue())
