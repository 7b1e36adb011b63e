"""What the report shows of a run's journal, read one line at a time.

A journal may hold millions of lines; the report needs only how many poses were stored, the
settle time of each and the first failures, so it reads the journal as a stream and keeps
those (a few numbers per pose), never the lines themselves. The lines it counts are those
:meth:`~microcal.formats.run_directory.RunDirectory.journal` keeps: each line that is a
journal line, the first for its pose.
"""

from __future__ import annotations

import json
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError
from ..formats.json_file import parse_schema
from ..formats.records import JournalLine
from ..procedures.rig_time import pose_rig_times_s
from .bounds import MAX_ROWS

__all__ = ["MAX_LINE_BYTES", "JournalSummary", "summarise_journal"]

#: The longest journal line read (a pose's line is about a kilobyte); a longer one is damaged.
MAX_LINE_BYTES = 1 << 20


@dataclass
class JournalSummary:
    """The journal's poses as the report shows them.

    Attributes
    ----------
    n_poses : int
        Poses journaled (intact lines, one per pose).
    n_ok : int
        Poses stored (status ``ok``).
    settle_s : (n,) float
        The settle time of every pose that records one, in journal order.
    failed : list of (pose, reason)
        The first :data:`~.bounds.MAX_ROWS` poses that failed, in journal order.
    n_failed : int
        All poses that failed.
    rig_time_s : (m,) float
        Rig time of every pose that records when it began, its moves and its settling
        (:func:`~microcal.procedures.rig_time.pose_rig_times_s`), in journal order.
    tip_std_um : (k, 3) float
        A one-camera run's journal (each stored pose with its tip in {M}, ``cov_um2``): the
        stated standard deviation of each tip per axis, in journal order.
    tip_frames : (k,) float
        Frames each of those tips took (the focus sweep's, or one against a stack).
    """

    n_poses: int = 0
    n_ok: int = 0
    settle_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    failed: list[tuple[int, str]] = field(default_factory=list)
    n_failed: int = 0
    rig_time_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    tip_std_um: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    tip_frames: FloatArray = field(default_factory=lambda: np.zeros(0))


def _tip(line: JournalLine) -> tuple[float, float, float, float] | None:
    """A one-camera pose's stated standard deviations (x, y, z, µm) and frames; None for a
    line without a finite 3 x 3 ``cov_um2`` (a stereo run's, a failed pose's)."""
    cov, frames = line.get("cov_um2"), line.get("frames")
    try:
        c = np.asarray(cov, dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if c.shape != (3, 3) or not np.all(np.isfinite(c)) or np.any(np.diagonal(c) < 0):
        return None
    n = float(frames) if isinstance(frames, int | float) else np.nan
    sx, sy, sz = np.sqrt(np.diagonal(c))
    return float(sx), float(sy), float(sz), n


def _lines(path: Path) -> Iterator[bytes | None]:
    """The file's lines without their line ends; None for a line over MAX_LINE_BYTES."""
    with path.open("rb") as f:
        while True:
            raw = f.readline(MAX_LINE_BYTES + 1)
            if not raw:
                return
            if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
                while raw and not raw.endswith(b"\n"):  # the rest of the long line, skipped
                    raw = f.readline(MAX_LINE_BYTES)
                yield None
                continue
            yield raw.removesuffix(b"\n")


def summarise_journal(path: Path) -> JournalSummary:
    """The summary of ``path`` (an empty one when there is no journal).

    Raises
    ------
    FormatError
        The journal exists but cannot be read.
    """
    out = JournalSummary()
    if not path.exists():
        return out
    seen: set[int] = set()
    settle = array("d")
    timed: list[tuple[float, float, float]] = []
    tips: list[tuple[float, float, float, float]] = []
    try:
        for raw in _lines(path):
            if raw is None or not raw.strip():
                continue
            try:
                line = parse_schema(JournalLine, json.loads(raw), path)
            except (FormatError, UnicodeDecodeError, RecursionError, ValueError):
                continue  # a damaged line: the run's readers name it, the report skips it
            if line.pose in seen:
                continue
            seen.add(line.pose)
            out.n_poses += 1
            if line.settle_s is not None:
                settle.append(float(line.settle_s))
                start, move = line.get("sim_time_s"), line.get("move_s")
                if isinstance(start, int | float) and isinstance(move, int | float):
                    timed.append((float(start), float(move), float(line.settle_s)))
            if line.status == "ok":
                out.n_ok += 1
                tip = _tip(line)
                if tip is not None:
                    tips.append(tip)
            else:
                out.n_failed += 1
                if len(out.failed) < MAX_ROWS:
                    out.failed.append((line.pose, line.reason or ""))
    except OSError as exc:
        raise FormatError(f"{path}: cannot be read ({exc.strerror})") from None
    out.settle_s = np.frombuffer(settle, dtype=np.float64).copy() if settle else np.zeros(0)
    if timed:
        start_s, move_s, settle_s = zip(*timed, strict=True)
        out.rig_time_s = pose_rig_times_s(start_s, move_s, settle_s)
    if tips:
        table = np.array(tips, dtype=np.float64)
        out.tip_std_um, out.tip_frames = table[:, :3], table[:, 3]
    return out
