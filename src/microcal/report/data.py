"""What a report is built from: the files of one run directory, each optional."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError, InputError
from ..formats.calibration_file import Calibration, load_calibration
from ..formats.cameras_file import CamerasRecord
from ..formats.json_file import parse_schema, read_versioned_json
from ..formats.measurements import Measurements, read_measurements
from ..formats.records import CheckRecord, Results, RunManifest, ValidationRecord
from ..formats.results_file import read_results
from ..formats.run_directory import RUN_FILE_NAMES, RunDirectory
from ..kinematics.extra_inputs import by_symbol
from ..kinematics.models import KinematicModel
from .journal_summary import JournalSummary, summarise_journal

__all__ = ["IdentifiedModel", "ModelErrors", "ReportInputs", "RunData", "load_run"]

#: The files a report reads, in the order a run produces them (the run directory's files
#: but its images and the report itself).
RUN_FILES = tuple(name for name in RUN_FILE_NAMES if name not in ("images", "report.html"))


@dataclass(frozen=True)
class ReportInputs:
    """Files of a run kept outside its directory, named by the user (each may be a link):
    the cameras.json, calibration.json and results.json the report reads instead of the run
    directory's own."""

    cameras: Path | None = None
    calibration: Path | None = None
    results: Path | None = None


@dataclass(frozen=True)
class IdentifiedModel:
    """An identified model of the calibration and its validation figures (None when the
    calibration records none)."""

    kind: str
    model: KinematicModel
    validation: ValidationRecord | None


@dataclass
class ModelErrors:
    """Prediction errors of one model on the poses it was not fitted to (Eq 5.1)."""

    kind: str
    model: KinematicModel
    validation: ValidationRecord | None
    poses: np.ndarray  # (n_validate,) int: the validation poses
    errors_um: FloatArray  # (n_validate,)


@dataclass
class RunData:
    """The parts of a run directory that exist; None or empty for what is missing."""

    run_dir: Path
    manifest: RunManifest | None = None
    commands_um: FloatArray | None = None  # (N, 3)
    journal: JournalSummary = field(default_factory=JournalSummary)  # what the report shows
    measurements: Measurements | None = None
    cameras: CamerasRecord | None = None
    calibration: Calibration | None = None
    results: Results | None = None
    checks: list[CheckRecord] = field(default_factory=list)  # the calibration's history

    @property
    def rig(self) -> dict[str, object] | None:
        """The rig run.json records (``{"driver": "sim", "preset": "thesis", ...}`` or
        ``{"driver": "hardware", ...}``); None without a run.json or a rig entry in it."""
        rig = self.manifest.rig if self.manifest is not None else None
        return dict(rig) if rig is not None else None

    def models(self) -> list[IdentifiedModel]:
        """Every identified model with its validation figures.

        A matrix model kept beside a polynomial one (for the matrix compensator) comes first.
        """
        out: list[IdentifiedModel] = []
        calibration = self.calibration
        for entry in calibration.manipulators.values() if calibration else []:
            try:
                matrix = entry.matrix_model
            except FormatError as exc:
                where = calibration.path if calibration is not None else "calibration.json"
                raise FormatError(
                    f"{where}: manipulators.{entry.name}.matrix_model: not a model's object "
                    f"({str(exc).partition(':')[2].strip()[:80]})"
                ) from None
            where = f"{calibration.path if calibration else 'calibration.json'}: manipulators."
            if matrix is not None and entry.model.kind != "matrix":
                found = _validation(
                    entry.matrix_validation, f"{where}{entry.name}.matrix_validation"
                )
                out.append(IdentifiedModel("matrix", matrix, found))
            found = _validation(entry.validation, f"{where}{entry.name}.validation")
            out.append(IdentifiedModel(entry.model.kind, entry.model, found))
        return out

    def model_errors(self) -> list[ModelErrors]:
        """Per identified model, its errors on the validation poses (recomputed from the files).

        The split is the one recorded in the model's validation object: the first ``n_fit``
        usable poses fitted, the rest validate.
        """
        m = self.measurements
        if m is None:
            return []
        out = []
        for found in self.models():
            model, validation = found.model, found.validation
            n_fit = validation.n_fit if validation is not None and validation.n_fit else 0
            if not 0 < n_fit < len(m.pose):
                continue
            names = [by_symbol(s).name for s in model.extra_inputs]
            if any(n not in m.extra for n in names):
                continue  # an input the measurements do not have
            u = np.column_stack([m.d_um, *(m.extra[n] for n in names)])
            err = np.linalg.norm(m.p_um[n_fit:] - model.predict_um(u[n_fit:]), axis=1)
            out.append(ModelErrors(found.kind, model, validation, m.pose[n_fit:], err))
        return out


def _validation(validation: object, where: str) -> ValidationRecord | None:
    """A calibration's validation object, typed; None for none (an empty one)."""
    if not validation:
        return None
    return parse_schema(ValidationRecord, validation, where)


def _grid(value: object) -> bool:
    """Whether ``value`` is a grid of numbers: rows of one length, at least one of each."""
    try:
        grid = np.asarray(value, dtype=np.float64)
    except (ValueError, TypeError):
        return False
    return grid.ndim == 2 and grid.size > 0


def _rows_of_four(value: object) -> bool:
    try:
        rows = np.asarray(value, dtype=np.float64)
    except (ValueError, TypeError):
        return False
    return rows.ndim == 2 and rows.shape[1] == 4


def _cameras(path: Path, link_ok: bool = False) -> CamerasRecord | None:
    """cameras.json as read, after its cameras load (a malformed one fails here, named)."""
    from ..formats.cameras_file import read_cameras

    if not path.exists() and not path.is_symlink():
        return None
    cameras = read_cameras(path, link_ok=link_ok)[0]
    raw = read_versioned_json(path, ("microcal.cameras/1",), link_ok=link_ok)
    for name, cam in cameras.items():
        residuals = cam.get("residuals_px", {})
        if not isinstance(residuals, dict) or not all(map(_rows_of_four, residuals.values())):
            raise FormatError(
                f"{path}: cameras.{name}.residuals_px: expected per image rows of [u, v, du, dv] px"
            )
        diagnostics = cam.get("diagnostics")
        umap = diagnostics.get("uncertainty_map_px") if isinstance(diagnostics, dict) else None
        if umap and not _grid(umap):
            raise FormatError(
                f"{path}: cameras.{name}.diagnostics.uncertainty_map_px: expected rows of one "
                "length of numbers (px)"
            )
    return parse_schema(CamerasRecord, raw, path)


def _checks(calibration: Path) -> list[CheckRecord]:
    """The history of checks of a calibration file, typed."""
    from ..formats.check_file import history_path, read_history

    where = history_path(calibration)
    try:
        history = read_history(calibration)
    except FormatError:
        raise
    except (UnicodeDecodeError, RecursionError, ValueError) as exc:  # bytes, nesting, digits
        raise FormatError(
            f"{where}: not a history of checks microcal reads ({type(exc).__name__}); move the "
            "file away to start a new history"
        ) from None
    checks = []
    for k, entry in enumerate(history, start=1):
        check = parse_schema(CheckRecord, entry, f"{where}, check {k}")
        for key in ("offset_um", "offset_std_um"):
            if len(getattr(check, key)) != 3:
                raise FormatError(f"{where}, check {k}: {key}: expected 3 values (x, y, z)")
        checks.append(check)
    return checks


def load_run(run_dir: str | os.PathLike[str], inputs: ReportInputs | None = None) -> RunData:
    """Read every report input that a run directory holds, and the files ``inputs`` names
    outside it (in their place).

    Raises
    ------
    InputError
        The directory does not exist or holds none of the run's files.
    FormatError
        A file that exists but cannot be read (its message names the file).
    """
    root = Path(run_dir)
    if not root.is_dir():
        raise InputError(f"{root}: not a directory (expected a run directory)")
    run = RunDirectory(root)
    present = {path.name for path in run.files() if path.parent == root} & set(RUN_FILES)
    given = inputs or ReportInputs()
    if not present and given == ReportInputs():
        raise InputError(
            f"{root}: holds none of {', '.join(RUN_FILES)}; is this a microcal run directory?"
        )
    data = RunData(root, manifest=run.manifest)
    if "commands.csv" in present:
        data.commands_um = run.commands()[1]
    data.journal = summarise_journal(root / "journal.jsonl")
    if "measurements.csv" in present:
        data.measurements = read_measurements(run.measurements_path, link_ok=False)
    if given.cameras is not None:
        data.cameras = _cameras(_given(given.cameras, "--cameras"), link_ok=True)
    else:
        data.cameras = _cameras(root / "cameras.json")
    calibration = given.calibration or root / "calibration.json"
    if given.calibration is not None or calibration.exists():
        data.calibration = load_calibration(_given(calibration, "--calibration"),
                                            link_ok=given.calibration is not None)  # fmt: skip
        if data.cameras is None and data.calibration.cameras:
            cameras = {"cameras": data.calibration.cameras}
            data.cameras = parse_schema(CamerasRecord, cameras, calibration)
    results = given.results or root / "results.json"
    if given.results is not None or results.exists():
        data.results = read_results(_given(results, "--results"),
                                    link_ok=given.results is not None)  # fmt: skip
    if data.calibration is not None:
        data.checks = _checks(calibration)
    return data


def _given(path: Path, option: str) -> Path:
    """A file the user named for the report: it must exist (a clear line otherwise)."""
    if not path.exists():
        raise InputError(f"{option} {path}: no such file")
    return path
