"""``microcal measure`` (3D positions of a run) and ``microcal report`` (its HTML report)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from typer import Argument, Option

from ..report.console import output_console, print_parts, staged_progress
from ._app import app

_RunDir = Annotated[Path, Argument(help="Run directory (commands.csv and images/).")]
_Cameras = Annotated[Path | None, Option(help="cameras.json (or a calibration.json with cameras).")]
_TARGET_HELP = "End-effector board or tool's tip (tip:needle:20:5); default: run.json's."
_Target = Annotated[str | None, Option(help=_TARGET_HELP)]


_Force = Annotated[bool, Option(help="Replace a measurements.csv that measured more poses.")]


@app.command(short_help="Measure the end-effector in 3D at every pose.")
def measure(
    run_dir: _RunDir, cameras: _Cameras = None, target: _Target = None, force: _Force = False
) -> None:
    """Measure the end-effector in 3D at every pose of a run; writes measurements.csv.

    Every image is measured only if it is the one the journal recorded (its SHA-256).

    Example: microcal measure runs/a --cameras cameras.json
    (a tool's tip instead of the run's target: --target tip:needle:20:5)
    """
    from ..report.text_tables import measurement_lines
    from ..workflows.measure import measure_run

    with staged_progress() as progress:
        tick = lambda done, n: progress("measuring", done, n)  # noqa: E731
        measured = measure_run(run_dir, cameras, target, force=force, progress=tick)
    print_parts(
        output_console(), [*measured.notes, *measurement_lines(measured.results, measured.path)]
    )


_ReportDir = Annotated[Path, Argument(help="Run directory (any of its files).")]
_ReportOut = Annotated[Path | None, Option("--out", "-o", help="Default RUN_DIR/report.html.")]
_ReportCameras = Annotated[Path | None, Option(help="cameras.json kept outside the run directory.")]
_ReportCalibration = Annotated[
    Path | None, Option(help="calibration.json kept outside the run directory.")
]
_ReportResults = Annotated[Path | None, Option(help="results.json kept outside the run directory.")]


@app.command(short_help="Write a run's calibration report (one HTML file).")
def report(
    run_dir: _ReportDir, out: _ReportOut = None, cameras: _ReportCameras = None,
    calibration: _ReportCalibration = None, results: _ReportResults = None,
) -> None:  # fmt: skip
    """Write the calibration report of a run: one self-contained HTML file with its figures.

    It shows what the run directory holds: the stereo calibration, the command design, the
    measurement uncertainty, the models and their validation errors, the pose-accuracy and
    decoupling tests, failed poses and provenance. Files kept beside the run rather than in
    it (one cameras.json and calibration.json for the runs of several devices) are named with
    --cameras, --calibration and --results.

    Example: microcal report runs/m1 --cameras cameras.json --calibration calibration.json
    """
    from ..workflows.report import ReportInputs
    from ..workflows.report import report as write

    inputs = ReportInputs(cameras=cameras, calibration=calibration, results=results)
    print(f"wrote {write(run_dir, out, inputs)}")
