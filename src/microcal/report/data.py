"""What a report is built from: the files of one run directory, each optional."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError, InputError
from ..formats.calibration_file import Calibration, load_calibration
from ..formats.json_file import read_versioned_json
from ..formats.measurements import Measurements, read_measurements
from ..formats.results_file import load_results
from ..formats.run_directory import RUN_FILE_NAMES, RunDirectory
from ..kinematics.extra_inputs import by_symbol
from ..kinematics.models import KinematicModel

__all__ = ["ModelErrors", "RunData", "load_run"]

#: The files a report reads, in the order a run produces them (the run directory's files
#: but its images and the report itself).
RUN_FILES = tuple(name for name in RUN_FILE_NAMES if name not in ("images", "report.html"))


@dataclass
class ModelErrors:
    """Prediction errors of one model on the poses it was not fitted to (Eq 5.1)."""

    kind: str
    model: KinematicModel
    validation: dict[str, Any]
    poses: np.ndarray  # (n_validate,) int: the validation poses
    errors_um: FloatArray  # (n_validate,)


@dataclass
class RunData:
    """The parts of a run directory that exist; None or empty for what is missing."""

    run_dir: Path
    manifest: dict[str, Any] = field(default_factory=dict)
    commands_um: FloatArray | None = None  # (N, 3)
    journal: list[dict[str, Any]] = field(default_factory=list)
    measurements: Measurements | None = None
    cameras: dict[str, Any] | None = None
    calibration: Calibration | None = None
    results: dict[str, Any] = field(default_factory=dict)
    checks: list[dict[str, Any]] = field(default_factory=list)  # the calibration's history

    @property
    def rig(self) -> dict[str, Any] | None:
        """The rig run.json records (``{"driver": "sim", "preset": "thesis", ...}`` or
        ``{"driver": "hardware", ...}``); None without a run.json or a rig entry in it."""
        rig = self.manifest.get("rig")
        return dict(rig) if isinstance(rig, dict) else None

    def models(self) -> list[tuple[str, KinematicModel, dict[str, Any]]]:
        """Every identified model as (kind, model, its validation object).

        A matrix model kept beside a polynomial one (for the matrix compensator) comes first.
        """
        out: list[tuple[str, KinematicModel, dict[str, Any]]] = []
        for entry in self.calibration.manipulators.values() if self.calibration else []:
            matrix = entry.matrix_model
            if matrix is not None and entry.model.kind != "matrix":
                out.append(("matrix", matrix, dict(entry.extra.get("matrix_validation", {}))))
            out.append((entry.model.kind, entry.model, entry.validation))
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
        for kind, model, validation in self.models():
            n_fit = int(validation.get("n_fit", 0))
            if not 0 < n_fit < len(m.pose):
                continue
            names = [by_symbol(s).name for s in model.extra_inputs]
            if any(n not in m.extra for n in names):
                continue  # an input the measurements do not have
            u = np.column_stack([m.d_um, *(m.extra[n] for n in names)])
            err = np.linalg.norm(m.p_um[n_fit:] - model.predict_um(u[n_fit:]), axis=1)
            out.append(ModelErrors(kind, model, validation, m.pose[n_fit:], err))
        return out


def _rows_of_four(value: object) -> bool:
    try:
        rows = np.asarray(value, dtype=np.float64)
    except (ValueError, TypeError):
        return False
    return rows.ndim == 2 and rows.shape[1] == 4


def _cameras(path: Path) -> dict[str, Any] | None:
    """cameras.json as read, after its cameras load (a malformed one fails here, named)."""
    from ..formats.cameras_file import read_cameras

    if not path.exists():
        return None
    raw = read_versioned_json(path, ("microcal.cameras/1",))
    read_cameras(path)
    for name, cam in raw["cameras"].items():
        residuals = cam.get("residuals_px", {})
        if not isinstance(residuals, dict) or not all(map(_rows_of_four, residuals.values())):
            raise FormatError(
                f"{path}: cameras.{name}.residuals_px: expected per image rows of [u, v, du, dv] px"
            )
    return raw


def load_run(run_dir: str | os.PathLike[str]) -> RunData:
    """Read every report input that a run directory holds.

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
    if not present:
        raise InputError(
            f"{root}: holds none of {', '.join(RUN_FILES)}; is this a microcal run directory?"
        )
    data = RunData(root)
    manifest = run.manifest
    if manifest is not None:
        data.manifest = manifest.to_json()
    if "commands.csv" in present:
        data.commands_um = run.commands()[1]
    data.journal = [line.to_json() for line in run.journal().values()]
    if "measurements.csv" in present:
        data.measurements = read_measurements(run.measurements_path)
    data.cameras = _cameras(root / "cameras.json")
    if (root / "calibration.json").exists():
        data.calibration = load_calibration(root / "calibration.json")
        if data.cameras is None and data.calibration.cameras:
            data.cameras = {"cameras": data.calibration.cameras}
    if (root / "results.json").exists():
        data.results = load_results(root / "results.json")
    if data.calibration is not None:
        from ..formats.check_file import read_history

        data.checks = read_history(root / "calibration.json")
    return data
