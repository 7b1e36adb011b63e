"""The command line: ``microcal --help``.

Every user error ends with one line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import sys
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.table import Table

from ._version import __version__
from .errors import MicrocalError

app = typer.Typer(
    name="microcal",
    help="Vision-based automatic calibration of microrobotic systems.",
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
def _root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = False,
) -> None:
    """Vision-based automatic calibration of microrobotic systems."""


@app.command()
def demo(
    seed: Annotated[int, typer.Option(help="Seed of all random draws.")] = 0,
    poses: Annotated[int, typer.Option(min=1, help="End-effector positions to measure.")] = 170,
) -> None:
    """Run what microcal can do today on synthetic data from the thesis's cameras.

    Example: microcal demo --seed 3 --poses 170
    """
    from .procedures.geometry_check import run_geometry_check

    console = Console()
    console.print(
        "[bold]microcal demo[/bold]: this version runs the [bold]camera-geometry core[/bold] only "
        "(stereo calibration by DLT and 3D measurement) on synthetic pixel coordinates from the "
        "thesis's two cameras. Rendered images, the simulated manipulator, kinematic "
        "identification, compensation and ISO 9283 tests are not built yet."
    )
    result = run_geometry_check(seed=seed, n_points=poses)
    table = Table(title="Stereo calibration (dot grid at 4 known heights, DLT)")
    for col in ("camera", "reprojection RMS px", "thesis px", "fx px", "fy px", "centre error µm"):
        table.add_column(col, justify="right")
    for c in result.cameras:
        table.add_row(
            c.name,
            f"{c.rms_px:.4f}",
            f"{c.thesis_rms_px:.4f}",
            f"{c.fx_px:.1f}",
            f"{c.fy_px:.1f}",
            f"{c.centre_error_um:.1f}",
        )
    console.print(table)
    sx, sy, sz = result.mean_predicted_std_um
    console.print(
        f"3D measurement of {result.n_points} end-effector positions (virtual-point noise of "
        f"thesis Table 4-1, optimal triangulation): RMS error {result.rms_error_um:.2f} µm, "
        f"max {result.max_error_um:.2f} µm; predicted std x/y/z {sx:.2f}/{sy:.2f}/{sz:.2f} µm; "
        f"Mahalanobis mean square {result.mahalanobis_mean_square:.2f} (3 = honest covariance)."
    )


def _fail(message: str) -> NoReturn:
    print(f"microcal: error: {message}", file=sys.stderr)
    sys.exit(2)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``microcal`` command: user errors end in one line and exit code 2."""
    args = sys.argv[1:] if argv is None else argv
    try:
        code = app(args=args or ["--help"], prog_name="microcal", standalone_mode=False)
    except typer.TyperException as exc:  # usage errors: bad option, value or command
        ctx = getattr(exc, "ctx", None)
        hint = f" (see: {ctx.command_path} --help)" if ctx is not None else ""
        _fail(f"{exc.format_message()}{hint}")
    except (typer.Abort, KeyboardInterrupt):
        _fail("interrupted")
    except MicrocalError as exc:
        _fail(str(exc))
    sys.exit(code if isinstance(code, int) else 0)
