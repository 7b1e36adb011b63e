"""The command group and its error handling: one line and exit code 2 for a user error."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from typer import Option
from typer.core import TyperGroup

from .._version import __version__
from ..errors import MicrocalError

WORKFLOW = ("demo", "calibrate-cameras", "stereo-calibrate", "scope-calibrate", "acquire",
            "measure", "fit", "solve", "evaluate", "report", "check")  # fmt: skip
INTERRUPTED = 130  # the exit code after Ctrl-C (128 + SIGINT, as shells report it)
Tolerance = Annotated[
    float,
    Option(
        min=0.01,
        help="The closed loop's tolerance, µm (90 % sure; no less than the cameras can "
        "confirm, which goto names when it is).",
    ),
]

#: A one-camera rig's scope calibration and its objective (goto, evaluate, check).
ScopeFile = Annotated[
    Path | None,
    Option("--scope", help="A one-camera rig: its camera's scope.json (scope-calibrate)."),
]
ObjectiveName = Annotated[
    str | None, Option(help="The objective's set in --scope (its only one by default).")
]


def fail(message: str, code: int = 2) -> NoReturn:
    """The one line a user error ends with, and its exit code (2; 130 when interrupted)."""
    print(f"microcal: error: {message}", file=sys.stderr)
    sys.exit(code)


class _Commands(TyperGroup):
    """User errors end here (not around the entry point): shells and CliRunner alike."""

    def main(  # type: ignore[override]
        self, args: list[str] | None = None, prog_name: str | None = None, **extra: Any
    ) -> Any:
        argv = sys.argv[1:] if args is None else list(args)
        extra.pop("standalone_mode", None)
        try:
            name = prog_name or "microcal"
            code = super().main(
                args=argv or ["--help"], prog_name=name, standalone_mode=False, **extra
            )
        except typer.TyperException as exc:  # usage errors: bad option, value or command
            ctx = getattr(exc, "ctx", None)
            hint = f" (see: {ctx.command_path} --help)" if ctx is not None else ""
            option = getattr(exc, "option_name", "") or ""
            if option[1:2].isdigit() or option[1:2] == ".":  # -10 taken for an option
                hint = f"; put -- before negative numbers, as in '... -- -10 0 0'{hint}"
            fail(f"{exc.format_message()}{hint}")
        except (typer.Abort, KeyboardInterrupt):
            fail("interrupted", INTERRUPTED)
        except MicrocalError as exc:  # a run stopped by Ctrl-C says how to resume, exits 130
            fail(str(exc), INTERRUPTED if getattr(exc, "interrupted", False) else 2)
        except Exception as exc:
            if type(exc).__module__.split(".")[0] != "cv2":  # OpenCV's cv2.error, unforeseen
                raise
            reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else "no reason"
            fail(f"OpenCV could not use an input ({reason}); check the images and --target")
        if code == INTERRUPTED:  # Ctrl-C (typer makes it this exit code, and says nothing)
            fail("interrupted", INTERRUPTED)
        sys.exit(code if isinstance(code, int) else 0)

    def list_commands(self, ctx: Any) -> list[str]:
        """In the order of a calibration, not alphabetically."""
        names = super().list_commands(ctx)
        return [n for n in WORKFLOW if n in names] + [n for n in names if n not in WORKFLOW]


app = typer.Typer(
    name="microcal",
    cls=_Commands,
    help="Vision-based automatic calibration of microrobotic systems.\n\n"
    "Example: microcal demo  (the whole calibration on the simulated platform; then open "
    "demo-out/report.html)",
    no_args_is_help=True,
    add_completion=False,
    rich_markup_mode=None,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        print(f"microcal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version.")) -> None:  # fmt: skip
    """Vision-based automatic calibration of microrobotic systems."""
