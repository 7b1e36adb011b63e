"""``microcal fit`` (identify a model) and ``microcal solve`` (the compensator)."""

from __future__ import annotations

import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated

from typer import Argument, Option

from ..report.console import output_console, print_parts
from ._app import app

ModelChoice = StrEnum("ModelChoice", {"matrix": "matrix", "polynomial": "polynomial"})
SelectChoice = StrEnum("SelectChoice", {"stepwise": "stepwise", "all": "all"})
_Source = Annotated[Path, Argument(help="Run directory or a measurements CSV file.")]
_Out = Annotated[Path, Option("--out", "-o", help="Calibration file to write or update.")]
_Model = Annotated[ModelChoice, Option(help="Kinematic model (thesis Eq 4.5 or 4.6).")]
_Select = Annotated[SelectChoice, Option(help="Polynomial terms: stepwise selection or all.")]
_Penter = Annotated[float, Option(help="Stepwise: p-value to enter.")]
_Premove = Annotated[float, Option(help="Stepwise: p-value to leave.")]
_Train = Annotated[int | None, Option(min=1, help="Fit on the first N poses (default: 110/170).")]
_Folds = Annotated[int | None, Option(min=2, help="Validate by K-fold cross-validation.")]
_FoldSeed = Annotated[int, Option(help="Seed of the cross-validation folds.")]
_Extra = Annotated[list[str] | None, Option(help="Extra input: temperature, approach (sx,sy,sz).")]
_Temperature = Annotated[bool, Option(help="Same as --extra temperature (T, T² terms).")]
_Approach = Annotated[bool | None, Option(
    "--approach/--no-approach", show_default=False,
    help="Fit the direction terms sx, sy, sz (reversal error). [default: when the run "
         "recorded approach directions]")]  # fmt: skip
_Name = Annotated[
    str | None, Option(help="Name of the manipulator in the calibration file. [the run's: m1]")
]
_Cameras = Annotated[Path | None, Option(help="cameras.json to include (for evaluate).")]
_Mat = Annotated[Path | None, Option(help="Also export the calibration as a .mat file.")]
_Exclude = Annotated[bool, Option(help="Leave out poses the model misses by > 6 robust sigmas.")]


@app.command(short_help="Identify a kinematic model from measurements.")
def fit(
    source: _Source, out: _Out = Path("calibration.json"), model: _Model = ModelChoice.polynomial,
    select: _Select = SelectChoice.stepwise, penter: _Penter = 0.05, premove: _Premove = 0.10,
    train: _Train = None, folds: _Folds = None, seed: _FoldSeed = 0, extra: _Extra = None,
    temperature: _Temperature = False, manipulator: _Name = None, cameras: _Cameras = None,
    mat: _Mat = None, exclude_outliers: _Exclude = False, approach: _Approach = None,
) -> None:  # fmt: skip
    """Identify a manipulator's kinematic model from measured positions.

    Example: microcal fit runs/a --model polynomial --cameras runs/a/cameras.json
    --out runs/a/calibration.json
    """
    from ..report.text_tables import fit_lines, outlier_lines
    from ..workflows.fit import FitRequest
    from ..workflows.fit import fit as run_fit

    names = (*(extra or []), *(["temperature"] if temperature else []))
    done = run_fit(FitRequest(
        source, out, model.value, select.value, penter, premove, train, folds, seed, names,
        manipulator, cameras, mat, exclude_outliers, approach,
    ))  # fmt: skip
    r = done.identification
    skipped = f" ({done.n_failed} failed poses skipped)" if done.n_failed else ""
    header = (f"{model.value} model of {done.entry.name!r} from {len(done.poses)} poses of "
              f"{done.measurements}{skipped}")  # fmt: skip
    wrote = "wrote " + " and ".join(str(w) for w in done.written)
    lines = fit_lines(r.model, r.validation, header, wrote)
    print_parts(output_console(), [*done.notes, *lines, *outlier_lines(r, done.poses)])


_Calibration = Annotated[Path, Argument(help="calibration.json")]
_Position = Annotated[list[float], Argument(help="X Y Z in {G}, µm (-- before negatives).")]
_Which = Annotated[str | None, Option(help="Manipulator name (optional if only one).")]
_Celsius = Annotated[float | None, Option(help="Ambient temperature, °C, for models with T terms.")]
_Limits = Annotated[str | None, Option(help="Soft limits LOW:HIGH per joint, µm, comma-separated.")]


@app.command(short_help="Print joint commands that reach given positions.")
def solve(
    calibration: _Calibration, position_um: _Position, manipulator: _Which = None,
    temperature: _Celsius = None, limits: _Limits = None,
) -> None:  # fmt: skip
    """Print the joint commands that put the end-effector at a position (the compensator).

    Example: microcal solve calibration.json 5000 4800 2700 --limits 0:8000,0:8000,0:4800
    """
    from ..report.text_tables import solution_lines
    from ..workflows.fit import SolveRequest
    from ..workflows.fit import solve as run_solve

    done = run_solve(
        SolveRequest(calibration, tuple(position_um), manipulator, temperature, limits)
    )
    print("dx_um dy_um dz_um\n" + " ".join(f"{v:.4f}" for v in done.solution.d_um), flush=True)
    for line in solution_lines(done.solution, done.entry):
        print(line, file=sys.stderr)
