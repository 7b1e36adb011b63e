"""Output to the terminal: tables and progress bars (rich), for the command line."""

from __future__ import annotations

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
def staged_progress(console: Console | None = None) -> Iterator[Callable[[str, int, int], None]]:
    """A progress callback (stage, done, total) showing one bar per stage while it runs."""
    from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeRemainingColumn

    bar = Progress(
        TextColumn("{task.description:<28}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeRemainingColumn(),
        console=console or Console(stderr=True),
        transient=True,
    )
    tasks: dict[str, TaskID] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=total)
        bar.update(tasks[stage], completed=done)

    with bar:
        yield progress
