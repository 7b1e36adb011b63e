"""Joint-command CSV files: a run's ``commands.csv`` and the tables a user passes in.

One reader serves them all (``commands.csv`` with its ``pose`` column, ``--design FILE.csv``,
``--known-displacements``): a UTF-8 file, with or without a byte-order mark, whose header
names the columns (``pose,dx_um,dy_um,dz_um``; other columns are ignored). Every error names
the file and, for a cell, its line.

```csv
pose,dx_um,dy_um,dz_um
1,4210.5,1022.9,3977.0
2,120.0,7400.2,80.5
```
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .._validation import FloatArray, excerpt
from ..errors import InputError, MicrocalError
from .atomic import write_text_atomic
from .safe_open import read_regular_bytes

__all__ = ["JOINT_COLUMNS", "read_joint_csv", "write_joint_csv"]

JOINT_COLUMNS = ("dx_um", "dy_um", "dz_um")


def read_joint_csv(
    path: str | os.PathLike[str],
    *,
    what: str | None = None,
    pose_column: bool | None = None,
    rows: int | None = None,
    min_rows: int = 1,
    columns: Sequence[str] = JOINT_COLUMNS,
    error: type[MicrocalError] = InputError,
    link_ok: bool = True,
) -> tuple[list[int] | None, FloatArray]:
    """Pose numbers and joint values (N, k) from a CSV file with a header.

    Parameters
    ----------
    path : path
        The file (UTF-8, a byte-order mark allowed).
    what : str, optional
        What the file is, to begin each message (``--design``, ``--known-displacements``).
    pose_column : bool, optional
        True: a ``pose`` column is required (positive whole numbers, each once); False: it is
        ignored; None (default): used when present.
    rows : int, optional
        The number of rows required.
    min_rows : int
        The fewest rows accepted (default 1).
    columns : sequence of str
        The value columns, in the order of the returned array's columns (default
        ``dx_um, dy_um, dz_um``).
    error : MicrocalError subclass
        What to raise: InputError (default) for a file the user gives, FormatError for a
        file of a run directory.
    link_ok : bool
        ``path`` may be a symbolic link to the file (one the user named, the default); False
        for a file of a run directory (:mod:`.safe_open`).

    Returns
    -------
    poses : list of int or None
        The ``pose`` column, or None when it is not read.
    values : (N, k) float
        One row per data line, finite.

    Raises
    ------
    MicrocalError (``error``)
        No such file, not UTF-8, a missing column, a cell that is not a finite number, a
        pose number that is not a positive whole number or appears twice, too few or the
        wrong number of rows. The message names the file and the line.
    """
    p = Path(path)
    where = f"{what} {p}" if what else str(p)
    try:
        text = read_regular_bytes(p, link_ok=link_ok).decode("utf-8-sig")
    except FileNotFoundError:
        raise error(f"{where}: no such file") from None
    except UnicodeDecodeError as exc:
        raise error(f"{where}: not UTF-8 text ({exc})") from None
    except OSError as exc:
        raise error(f"{where}: cannot be read ({exc.strerror or exc})") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    wanted = [*(["pose"] if pose_column else []), *columns]
    try:
        header = [name.strip() for name in next(reader)]
    except StopIteration:
        raise error(f"{where}: empty; expected a header {','.join(wanted)}") from None
    except csv.Error as exc:
        raise error(f"{where}, line 1: not CSV ({exc})") from None
    missing = [c for c in wanted if c not in header]
    if missing:
        raise error(
            f"{where}, line 1: missing column(s) {missing}; expected a CSV with columns "
            f"{','.join(wanted)}, got {_shown_header(header)}"
        )
    use_pose = pose_column is not False and "pose" in header
    index = [header.index(c) for c in columns]
    pose_index = header.index("pose") if use_pose else -1
    poses: list[int] = []
    first_line: dict[int, int] = {}
    values: list[list[float]] = []
    while True:
        try:
            row = next(reader)
        except StopIteration:
            break
        except csv.Error as exc:
            raise error(f"{where}, line {reader.line_num}: not CSV ({exc})") from None
        line = reader.line_num
        if not any(cell.strip() for cell in row):
            continue  # a blank line
        if len(row) < len(header):
            raise error(f"{where}, line {line}: {len(row)} cells, expected {len(header)}")
        if use_pose:
            pose = _pose(row[pose_index], where, line, error)
            if pose in first_line:
                raise error(
                    f"{where}, line {line}: pose {pose} appears twice (first on line "
                    f"{first_line[pose]})"
                )
            first_line[pose] = line
            poses.append(pose)
        values.append(
            [_number(row[i], columns[k], where, line, error) for k, i in enumerate(index)]
        )
    if rows is not None and len(values) != rows:
        raise error(f"{where}: {len(values)} rows of {','.join(columns)}, expected {rows}")
    if len(values) < min_rows:
        raise error(
            f"{where}: {len(values)} rows of {','.join(columns)}, expected at least {min_rows}"
        )
    d = np.array(values, dtype=np.float64).reshape(len(values), len(columns))
    return (poses if use_pose else None), d


_COLUMN_NAME = re.compile(r"[A-Za-z0-9_. ()-]{0,32}")


def _shown_header(header: list[str]) -> str:
    """The header found, quoted when it is a line of column names; otherwise only what it is
    not (the first line of another kind of file is not quoted)."""
    if len(header) <= 12 and all(_COLUMN_NAME.fullmatch(name) for name in header):
        return ascii(",".join(header))
    return f"a first line of {len(header)} cell(s) that is not a header of column names"


def _number(cell: str, column: str, where: str, line: int, error: type[MicrocalError]) -> float:
    try:
        value = float(cell.strip())
    except ValueError:
        raise error(f"{where}, line {line}: {column} = {excerpt(cell)} is not a number") from None
    if not np.isfinite(value):
        raise error(f"{where}, line {line}: {column} = {excerpt(cell)} is not a finite number")
    return value


def _pose(cell: str, where: str, line: int, error: type[MicrocalError]) -> int:
    try:
        pose = int(cell.strip())
    except ValueError:
        raise error(f"{where}, line {line}: pose {excerpt(cell)} is not a whole number") from None
    if pose < 1:
        raise error(f"{where}, line {line}: pose {pose}; poses are numbered from 1")
    return pose


def write_joint_csv(
    path: str | os.PathLike[str], d_um: FloatArray, columns: Sequence[str] = JOINT_COLUMNS
) -> Path:
    """Write ``pose`` (from 1) and the joint values (4 decimals) atomically."""
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["pose", *columns])
    for i, row in enumerate(np.asarray(d_um, dtype=np.float64), start=1):
        w.writerow([i, *(f"{v:.4f}" for v in row)])
    return write_text_atomic(path, out.getvalue())
