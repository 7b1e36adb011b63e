"""The command line: ``microcal --help``.

A shell: each command (one module per command or pair) parses, calls one procedure or
formats function and prints; a user error ends with one line on stderr and exit code 2.
"""

from __future__ import annotations

from . import (
    acquire,
    check,
    demo,
    evaluate,
    fit,
    goto,
    measure,
    scope,
    stereo,
    study,
    tool_centre,
    twin,
    ui,
)
from ._app import WORKFLOW, app

__all__ = ["WORKFLOW", "app", "main"]
# registered on import
_COMMANDS = (
    acquire, check, demo, evaluate, fit, goto, measure, scope, stereo, study, tool_centre, twin,
    ui,
)  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``microcal`` command: user errors end in one line and exit code 2."""
    app(args=argv)
