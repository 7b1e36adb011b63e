"""An adaptive run read whole: every batch's measurements in one measurements.csv, and the
calibration its design ends with, as ``microcal fit`` writes and repeats it.

``microcal acquire --design adaptive`` acquires its batches as run directories of their own
(``RUN/batch-001`` ...). When it stops, :func:`merge_measurements` writes
``RUN/measurements.csv``: every pose of the run, numbered 1 to N in the order it was
acquired (the start, then batch after batch), each batch's rows as measured. Then
:func:`fit_adaptive_run` fits the design's model (the ``smooth`` family over the run's
workspace, with the approach directions and, over a span of 0.1 °C or more, the
temperature: :mod:`~microcal.procedures.adaptive`) on every measured pose and adds it to
``RUN/calibration.json``. ``microcal fit RUN`` calls the same function on the same file, so
it writes the same numbers.

Its validation: the last batch, predicted by the model of every pose before it (the poses
the run chose last, which no fit had seen).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DegenerateDataError, FormatError, InputError
from ..formats.atomic import write_text_atomic
from ..formats.calibration_file import Calibration
from ..formats.measurements import read_measurements
from ..formats.run_directory import RunDirectory
from ..kinematics.adaptive_design import joint_inputs
from ..kinematics.extra_inputs import APPROACH_INPUTS
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..kinematics.validation import validate_split
from ..procedures.adaptive import Measured
from ..procedures.identification import Identification, find_outliers, identify
from . import calibration_update as update
from .adaptive_batches import ADAPTIVE_FILE, ADAPTIVE_FORMAT, BatchedDesign

__all__ = [
    "MEASUREMENTS",
    "batch_dirs",
    "check_adaptive_fit_options",
    "fit_adaptive_run",
    "merge_measurements",
    "predicted_line",
]

#: Every pose of an adaptive run, in the run directory.
MEASUREMENTS = "measurements.csv"


def batch_dirs(run: Path) -> list[Path]:
    """The run's batch directories, in order (``batch-001`` ...)."""
    out = sorted(p for p in run.glob("batch-[0-9][0-9][0-9]") if p.is_dir())
    if not out:
        raise FormatError(f"{run}: an adaptive run without a batch (batch-001)")
    return out


def merge_measurements(run: Path) -> Path:
    """Write ``RUN/measurements.csv``: every batch's rows, poses numbered through the run
    (a batch's pose k is pose ``k`` plus the poses of the batches before it), written
    atomically.

    Raises
    ------
    FormatError
        A batch not measured, or batches measured into different columns.
    """
    header: list[str] | None = None
    rows: list[list[str]] = []
    offset = 0
    for batch in batch_dirs(run):
        path = batch / MEASUREMENTS
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise FormatError(f"{path}: cannot be read ({exc}); resume the run") from None
        table = list(csv.reader(io.StringIO(text)))
        if not table or table[0][:1] != ["pose"]:
            raise FormatError(f"{path}: expected a measurements table (header from 'pose')")
        if header is not None and table[0] != header:
            raise FormatError(f"{path}: other columns than the batches before it")
        header = table[0]
        rows += [[str(offset + int(row[0])), *row[1:]] for row in table[1:] if row]
        offset += len(RunDirectory.open(batch).commands()[0])
    assert header is not None
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return write_text_atomic(run / MEASUREMENTS, out.getvalue())


def _options(run: Path) -> dict[str, Any]:
    path = run / ADAPTIVE_FILE
    try:
        options: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path}: cannot be read ({exc})") from None
    if options.get("format") != ADAPTIVE_FORMAT or "workspace_um" not in options:
        raise FormatError(f"{path}: expected format {ADAPTIVE_FORMAT!r} with its workspace_um")
    return options


def _measured(run: Path, path: Path) -> Measured:
    """Every pose of the run (its commands from the batches), measured as ``path`` says
    (NaN where it failed)."""
    d = np.vstack([np.asarray(RunDirectory.open(b).commands()[1], dtype=np.float64)
                   for b in batch_dirs(run)])  # fmt: skip
    meas = read_measurements(path, min_poses=1, link_ok=False)
    n = len(d)
    p, signs = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    temps = np.zeros(n)
    row = meas.pose.astype(int) - 1
    if row.size and (row.min() < 0 or row.max() >= n):
        raise FormatError(f"{path}: poses beyond the run's {n}")
    p[row] = meas.p_um
    for k, name in enumerate(APPROACH_INPUTS):
        values = meas.extra.get(name)
        if values is not None:
            signs[row, k] = values
    if meas.temperature_c is not None:
        temps[row] = np.nan_to_num(meas.temperature_c)
    return Measured(d, p, signs, temps)


def fit_adaptive_run(
    run: Path,
    out: Path,
    cameras: Path | None = None,
    manipulator: str | None = None,
) -> tuple[Calibration, ManipulatorCalibration, Identification, np.ndarray, int]:
    """Fit an adaptive run's design model on every pose of ``RUN/measurements.csv`` and add
    it to ``out`` (module docstring).

    Returns
    -------
    calibration : Calibration
        ``out`` as written.
    entry : ManipulatorCalibration
        As written.
    identification : Identification
        The model, its validation (the last batch) and the data used.
    poses : (N,) int
        The poses fitted.
    n_failed : int
        Poses whose measurement failed.

    Raises
    ------
    FormatError, DegenerateDataError
        A run not read whole (no measurements.csv: resume it), too few poses.
    """
    options = _options(run)
    path = run / MEASUREMENTS
    if not path.is_file():
        raise FormatError(f"{path}: missing; microcal acquire --out {run} --resume writes it")
    measured = _measured(run, path)
    design = BatchedDesign(options, np.asarray(options["workspace_um"], dtype=np.float64))
    model = design.fit(measured)
    if model is None:
        raise DegenerateDataError(f"{run}: too few poses measured to fit the adaptive model")
    ok = measured.ok
    inputs = design.inputs(measured)
    u = joint_inputs(measured.d_um[ok], measured.signs[ok], measured.temperature_c[ok], inputs)
    p = measured.p_um[ok]
    starts = design.batch_starts(len(measured))
    last_start = starts[-2] if len(starts) > 1 and starts[-1] == len(measured) else starts[-1]
    n_fit = int(ok[:last_start].sum())
    if not 0 < n_fit < len(u):
        n_fit = max(1, len(u) - 1)
    val = validate_split(lambda uf, pf: design.fit_rows(uf, inputs, pf), u, p, n_fit)
    validation: dict[str, object] = {
        "method": f"last batch ({len(u) - n_fit} poses) by the fit of the {n_fit} before it; "
                  f"the model: all {len(u)} poses",
        **val.as_dict(),
    }  # fmt: skip
    figure, worst = design.predicted_um(model, measured, inputs)
    inflation = float(np.sqrt(max(1.0, design.calibration(measured, inputs))))
    held = design.held_um
    matrix = identify(measured.d_um[ok], p, "matrix", train=n_fit, held_um=held)
    extra: dict[str, object] = {
        "joint_range_um": np.column_stack([measured.d_um[ok].min(axis=0),
                                           measured.d_um[ok].max(axis=0)]).tolist(),
        "matrix_model": matrix.model.to_dict(),
        "matrix_validation": matrix.validation,
        "adaptive": {"until_um": float(options["until_um"]), "poses": len(measured),
                     "predicted_um": figure * inflation, "max_predicted_um": worst * inflation,
                     "inflation": inflation, "level": design.settings.level},
    }  # fmt: skip
    manifest = RunDirectory(batch_dirs(run)[0]).manifest
    name = manipulator or update.measured_device(manifest)
    entry = ManipulatorCalibration(name, model, validation, extra)
    written = update.add_manipulator(out, entry, cameras, {"measurements": path}, "polynomial",
                                     manifest)  # fmt: skip
    found = find_outliers(model, u, p)
    ident = Identification(model, validation, val, None, u, p, found)
    poses: np.ndarray = np.flatnonzero(ok) + 1
    return written, written.manipulators[name], ident, poses, int((~ok).sum())


def check_adaptive_fit_options(request: Any) -> None:
    """Refuse ``microcal fit`` options an adaptive run does not take: it is fitted as its
    design fits.

    Raises
    ------
    InputError
    """
    given = [flag for flag, set_ in (
        ("--model matrix", request.model != "polynomial"),
        ("--select", request.select != "stepwise"),
        ("--train", request.train is not None), ("--folds", request.folds is not None),
        ("--extra", bool(request.extra)), ("--approach", request.approach is not None),
        ("--exclude-outliers", request.exclude_outliers), ("--mat", request.mat is not None),
    ) if set_]  # fmt: skip
    if given:
        raise InputError(
            f"{request.source}: an adaptive run is fitted as its design fits (all its poses); "
            f"leave out {', '.join(given)}, or fit {request.source / MEASUREMENTS} instead"
        )


def predicted_line(entry: ManipulatorCalibration) -> str:
    """One line: the written calibration's predicted error against the tolerance."""
    a = entry.extra.get("adaptive")
    if not isinstance(a, dict):
        return ""
    level, figure, until = float(a["level"]), float(a["predicted_um"]), float(a["until_um"])
    return (f"predicted {100 * level:.0f} % error of the compensated tip over the workspace "
            f"{figure:.3g} µm (tolerance {until:g} µm)")  # fmt: skip
