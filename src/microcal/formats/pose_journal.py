"""A journal of poses as JSON lines, each on disk before the next pose begins.

The one-camera acquisition measures each tip at its pose and keeps no images; its journal is
one line per pose (the pose's record and its tip), appended, flushed and synced to disk at
once, so a run stopped at any moment keeps every pose measured before (a line being written
when it stopped is the last, and a reader can drop it).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..json_value import JsonValue

__all__ = ["PoseJournal"]


class PoseJournal:
    """Appends lines to ``path`` (made new: an existing file is replaced)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.path.write_text("", encoding="utf-8")
        self.lines = 0

    def append(self, line: dict[str, JsonValue]) -> None:
        """Write one line and sync it to disk."""
        text = json.dumps(line, allow_nan=False) + "\n"
        with self.path.open("a", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        self.lines += 1
