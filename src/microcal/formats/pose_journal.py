"""A journal of poses as JSON lines, each on disk before the next pose begins.

The one-camera acquisition measures each tip at its pose and keeps no images; its journal is
one line per pose (the pose's record and its tip), appended, flushed and synced to disk at
once, so a run stopped at any moment keeps every pose measured before (a line being written
when it stopped is the last, and a reader can drop it): :meth:`PoseJournal.resume` reads the
lines stored, drops such a torn last line, and appends after them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..errors import FormatError
from ..json_value import JsonValue
from .atomic import write_text_atomic
from .safe_open import read_regular_text

__all__ = ["PoseJournal"]


class PoseJournal:
    """Appends lines to ``path`` (made new: an existing file is replaced)."""

    def __init__(self, path: str | os.PathLike[str], *, keep: bool = False) -> None:
        self.path = Path(path)
        if not keep:
            self.path.write_text("", encoding="utf-8")
        self.lines = 0

    @classmethod
    def resume(cls, path: str | os.PathLike[str]) -> tuple[PoseJournal, list[dict[str, JsonValue]]]:
        """The journal at ``path`` opened to append after its lines, and those lines (a torn
        last line, written when a run was stopped, dropped from the file).

        Raises
        ------
        FormatError
            A line before the last that is not a JSON object (the journal was edited).
        """
        p = Path(path)
        text = read_regular_text(p) if p.exists() else ""
        raw = text.splitlines()
        lines: list[dict[str, JsonValue]] = []
        for i, line in enumerate(raw):
            try:
                value = json.loads(line)
            except ValueError:
                value = None
            if not isinstance(value, dict):
                if i == len(raw) - 1:  # the line being written when the run stopped
                    write_text_atomic(p, "".join(r + "\n" for r in raw[:-1]))
                    break
                raise FormatError(f"{p}, line {i + 1}: not a pose's line; the journal was edited")
            lines.append(value)
        else:
            if text and not text.endswith("\n"):  # a whole line without its end
                write_text_atomic(p, text + "\n")
        journal = cls(p, keep=True)
        journal.lines = len(lines)
        return journal, lines

    def append(self, line: dict[str, JsonValue]) -> None:
        """Write one line and sync it to disk."""
        text = json.dumps(line, allow_nan=False) + "\n"
        with self.path.open("a", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        self.lines += 1
