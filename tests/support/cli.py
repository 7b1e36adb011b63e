"""Running ``microcal`` as a user would: in this process (fast), or in its own process where
the process itself is what a test checks (its exit status, what a shell sees, signals)."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from dataclasses import dataclass

from typer.testing import CliRunner

#: The width ``python -m microcal`` prints to when its output is not a terminal.
COLUMNS = "80"


@dataclass(frozen=True)
class Ran:
    """What a command left: its exit code and both outputs (as a finished process has)."""

    returncode: int
    stdout: str
    stderr: str


def invoke_microcal(*args: object, cwd: str | os.PathLike[str] | None = None) -> Ran:
    """Run ``microcal ARGS`` in this process through typer's CliRunner.

    The exit code, standard output and standard error are those of ``python -m microcal ARGS``
    with no standard input and its output captured (80 columns, as when it is not a terminal):
    the command group turns a user error into one line on stderr and exit code 2 in either
    case. An exception that is not a user error is raised here, where ``python -m microcal``
    would print its traceback and exit with 1.
    """
    from microcal.cli import app

    with contextlib.chdir(cwd) if cwd is not None else contextlib.nullcontext():
        result = CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": COLUMNS})
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return Ran(result.exit_code, result.stdout, result.stderr)


def run_microcal(*args: object, cwd=None) -> subprocess.CompletedProcess[str]:
    """Run ``python -m microcal ARGS`` as a user would: no standard input, output captured."""
    return subprocess.run([sys.executable, "-m", "microcal", *map(str, args)], capture_output=True,
                          text=True, check=False, stdin=subprocess.DEVNULL, cwd=cwd)  # fmt: skip
