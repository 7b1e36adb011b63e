"""Output to the terminal: tables and progress bars (rich), for the command line."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.table import Table

from .text_tables import TextTable

__all__ = ["print_parts", "print_table", "staged_progress"]


def print_table(console: Console, table: TextTable) -> None:
    """Print a :class:`~microcal.report.text_tables.TextTable`."""
    out = Table(title=table.title)
    for i, col in enumerate(table.columns):
        out.add_column(col, justify="left" if i == 0 and table.first_left else "right")
    for row in table.rows:
        out.add_row(*row)
    console.print(out)


def print_parts(console: Console, parts: list[TextTable | str]) -> None:
    """Print tables and lines in order; lines as they are (no markup, no wrapping)."""
    for part in parts:
        if isinstance(part, TextTable):
            print_table(console, part)
        else:
            console.print(part, markup=False, highlight=False, emoji=False, soft_wrap=True)


@contextmanager
def staged_progress(
    console: Console | None = None, clock: Callable[[], float] = time.monotonic
) -> Iterator[Callable[[str, int, int], None]]:
    """A progress callback (stage, done, total).

    On a terminal: one bar per stage while it runs, with its count and the time left. Where
    the output is not a terminal (a log, a pipe, a notebook): one line per step, ``stage:
    done/total, elapsed, about ... left``, at most one per percent of a stage (so a long stage
    writes at most about a hundred lines).
    """
    from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeRemainingColumn

    out = console or Console(stderr=True)
    if not out.is_terminal:
        started: dict[str, float] = {}
        shown: dict[str, int] = {}

        def lines(stage: str, done: int, total: int) -> None:
            now = clock()
            t0 = started.setdefault(stage, now)
            step = int(100 * done / total) if total > 0 else done
            if shown.get(stage) == step and done != total:
                return
            shown[stage] = step
            line = f"{stage}: {done}/{total}, {_duration(now - t0)} elapsed"
            if 0 < done < total:
                line += f", about {_duration((now - t0) / done * (total - done))} left"
            out.print(line, markup=False, highlight=False, emoji=False, soft_wrap=True)

        yield lines
        return

    bar = Progress(
        TextColumn("{task.description:<28}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeRemainingColumn(),
        console=out,
        transient=True,
    )
    tasks: dict[str, TaskID] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=total)
        bar.update(tasks[stage], completed=done)

    with bar:
        yield progress


def _duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``1 h 02 min``."""
    s = round(seconds)
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"
