"""How much of a run the report shows: its tables, texts and figures are bounded.

The report's inputs may come from anywhere, so nothing in them may make the page or the
time to build it grow faster than what it shows: a table shows at most :data:`MAX_ROWS`
rows and says how many it left out, a text from a file at most :data:`MAX_TEXT_CHARS`
characters, a figure at most :data:`MAX_PANELS` cameras and :data:`MAX_POINTS` points per
series. Every bound lies far above what a calibration run produces, so the report of a good
run shows all of it.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence, Sized
from dataclasses import dataclass
from itertools import islice
from typing import Generic, TypeVar

import numpy as np

__all__ = [
    "MAX_LABEL_CHARS",
    "MAX_PANELS",
    "MAX_POINTS",
    "MAX_ROWS",
    "MAX_TEXT_CHARS",
    "Shown",
    "clip",
    "first",
    "last",
    "thinned",
]

#: Rows of one table (or items of one list) the page shows.
MAX_ROWS = 100
#: Characters of one text from an input file the page shows (a name, a reason, a value).
MAX_TEXT_CHARS = 300
#: Cameras (panels) of one figure.
MAX_PANELS = 8
#: Points of one plotted series (a scatter, a line); more are thinned evenly.
MAX_POINTS = 50_000
#: Characters of one label in a figure (a camera's, a view's or a device's name).
MAX_LABEL_CHARS = 40

T = TypeVar("T")


@dataclass(frozen=True)
class Shown(Generic[T]):
    """The rows a table shows and how many it leaves out (``more``)."""

    rows: list[T]
    more: int = 0

    def __iter__(self) -> Iterator[T]:
        return iter(self.rows)

    def __len__(self) -> int:
        return len(self.rows)

    def __bool__(self) -> bool:
        return bool(self.rows)


def first(items: Iterable[T], limit: int = MAX_ROWS) -> Shown[T]:
    """The first ``limit`` of ``items`` and the count of the rest (an iterable is consumed
    once: a long journal is counted, never held)."""
    it = iter(items)
    rows = list(islice(it, limit))
    more = len(items) - len(rows) if isinstance(items, Sized) else sum(1 for _ in it)
    return Shown(rows, more)


def last(items: Sequence[T], limit: int = MAX_ROWS) -> Shown[T]:
    """The last ``limit`` of ``items`` (the most recent) and the count of the earlier ones."""
    rows = list(items[-limit:]) if limit else []
    return Shown(rows, len(items) - len(rows))


def clip(text: str, limit: int = MAX_TEXT_CHARS) -> str:
    """``text`` cut to ``limit`` characters, an ellipsis marking a cut."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


def thinned(n: int, limit: int = MAX_POINTS) -> slice:
    """A slice keeping at most ``limit`` of ``n`` points, evenly spaced (all of them when
    there are no more than ``limit``)."""
    return slice(None) if n <= limit else slice(None, None, int(np.ceil(n / limit)))
