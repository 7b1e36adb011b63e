"""Output to the terminal: tables and progress bars (rich), for the command line."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.table import Table

from .text_tables import TextTable

__all__ = ["LOG_WIDTH", "output_console", "print_parts", "print_table", "staged_progress"]

#: Width of the tables a command prints where its output is not a terminal (a log file, a
#: pipe) and ``COLUMNS`` does not say: a log is read whole, and a table split into parts to
#: fit the 80 columns rich takes there is harder to read.
LOG_WIDTH = 160


def output_console() -> Console:
    """The console a command prints its results to: the terminal's width on a terminal, else
    ``COLUMNS`` or :data:`LOG_WIDTH` for its tables, and its lines not wrapped (a log's
    reader or a program reads each whole)."""
    console = Console()
    if console.is_terminal:
        return console
    width = int(os.environ["COLUMNS"]) if os.environ.get("COLUMNS", "").isdigit() else LOG_WIDTH
    return Console(width=width, soft_wrap=True)


def print_table(console: Console, table: TextTable) -> None:
    """Print a :class:`~microcal.report.text_tables.TextTable` within the console's width.

    A cell is never cut nor wrapped (a number is read whole), nor is a heading. A table wider
    than the console is printed as several, each with the first column and as many of the
    others as fit (titled ``(1/2)``, ``(2/2)``).
    """
    table = without_empty_columns(table)
    groups = column_groups(table, console.width)
    for k, group in enumerate(groups):
        title = table.title if len(groups) == 1 else f"{table.title} ({k + 1}/{len(groups)})"
        if title:  # a line of its own, wrapped between words, not squeezed into the box
            console.print(title, markup=False, highlight=False, emoji=False, style="italic")
        out = Table()
        for i in group:
            left = i == 0 and table.first_left
            out.add_column(table.columns[i], justify="left" if left else "right", no_wrap=True,
                           min_width=_cell_width(table, i))  # fmt: skip
        for row in table.rows:
            out.add_row(*(row[i] if i < len(row) else "" for i in group))
        console.print(out)


def without_empty_columns(table: TextTable) -> TextTable:
    """The table without the columns (but the first) whose every cell is empty: a figure no
    row has (a lens model's held-out error when the model was fixed) takes no room."""

    def shown(i: int) -> bool:
        return any(i < len(r) and r[i].strip() for r in table.rows)

    keep = [i for i in range(len(table.columns)) if i == 0 or not table.rows or shown(i)]
    if len(keep) == len(table.columns):
        return table
    return TextTable(table.title, [table.columns[i] for i in keep],
                     [[r[i] if i < len(r) else "" for i in keep] for r in table.rows],
                     table.first_left)  # fmt: skip


def _cell_width(table: TextTable, i: int) -> int:
    """The widest cell of column ``i``, its heading included (neither is wrapped)."""
    cells = [len(row[i]) for row in table.rows if i < len(row)]
    return max([*cells, len(table.columns[i]), 1])


def column_groups(table: TextTable, width: int) -> list[list[int]]:
    """The columns of each table printed so that each fits ``width`` characters: the first
    column in every one, then the others in order, as many as fit (at least one)."""
    border = 1  # the box's right edge; each column takes its width + 3 (padding, left edge)
    first = _cell_width(table, 0) + 3
    groups: list[list[int]] = []
    current: list[int] = [0]
    used = border + first
    for i in range(1, len(table.columns)):
        need = _cell_width(table, i) + 3
        if used + need > width and len(current) > 1:
            groups.append(current)
            current, used = [0], border + first
        current.append(i)
        used += need
    groups.append(current)
    return groups


def print_parts(console: Console, parts: list[TextTable | str]) -> None:
    """Print tables and lines in order; lines as they are (no markup, no wrapping)."""
    for part in parts:
        if isinstance(part, TextTable):
            print_table(console, part)
        else:
            console.print(part, markup=False, highlight=False, emoji=False, soft_wrap=True)


#: Where the output is not a terminal, a stage's progress lines: at most one per this share.
LOG_STEPS = 20


@contextmanager
def staged_progress(
    console: Console | None = None, clock: Callable[[], float] = time.monotonic
) -> Iterator[Callable[[str, int, int], None]]:
    """A progress callback (stage, done, total).

    On a terminal: one bar per stage while it runs, with its count and the time left. Where
    the output is not a terminal (a log, a pipe, a notebook): one line per step, ``stage:
    done/total, elapsed, about ... left``, at most one per twentieth of a stage (so a stage of
    170 poses writes some 20 lines, not 170).
    """
    from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeRemainingColumn

    out = console or Console(stderr=True)
    if not out.is_terminal:
        # lines go with the command's other output: standard error keeps to the one line
        # of an error
        out = console if console is not None and not console.stderr else Console()
        started: dict[str, float] = {}
        shown: dict[str, int] = {}

        def lines(stage: str, done: int, total: int) -> None:
            now = clock()
            t0 = started.setdefault(stage, now)
            step = int(LOG_STEPS * done / total) if total > 0 else done
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
