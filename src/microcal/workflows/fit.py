"""``microcal fit`` (identify a manipulator's model) and ``microcal solve`` (its compensator)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..formats.calibration_file import Calibration, load_calibration
from ..formats.measurements import read_measurements
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..procedures.compensation import Solution, solve_position
from ..procedures.identification import Identification, calibrate_manipulator
from ..procedures.planning import MIN_DESIGN_POSES
from . import calibration_update as update
from .options import parse_limits, parse_number, parse_position

__all__ = ["FitRequest", "FitResult", "SolveRequest", "SolveResult", "fit", "solve"]


@dataclass(frozen=True)
class FitRequest:
    """What ``microcal fit`` is asked (its options, as typed values).

    Attributes
    ----------
    source : Path
        A run directory (its measurements.csv) or a measurements CSV file.
    out : Path
        calibration.json to write, or to update with this manipulator's entry.
    extra : tuple of str
        Extra inputs to model (``temperature``, ``approach``).
    manipulator : str, optional
        The entry's name; the measured run's device (run.json), else ``m1``.
    cameras : Path, optional
        A cameras.json whose cameras the calibration carries.
    mat : Path, optional
        Also export the calibration as a MATLAB .mat file.
    """

    source: Path
    out: Path = Path("calibration.json")
    model: Literal["matrix", "polynomial"] = "polynomial"
    select: Literal["stepwise", "all"] = "stepwise"
    penter: float = 0.05
    premove: float = 0.10
    train: int | None = None
    folds: int | None = None
    seed: int = 0
    extra: tuple[str, ...] = ()
    manipulator: str | None = None
    cameras: Path | None = None
    mat: Path | None = None
    exclude_outliers: bool = False


@dataclass(frozen=True)
class FitResult:
    """What ``microcal fit`` did.

    Attributes
    ----------
    measurements : Path
        The measurements CSV file fitted.
    entry : ManipulatorCalibration
        The manipulator's calibration, as written.
    identification : Identification
        The fit of the requested model (its validation and outliers).
    poses : (N,) int
        The measured poses' numbers (failed poses left out).
    n_failed : int
        Poses whose measurement failed, skipped.
    written : tuple of Path
        The files written (the calibration, and the .mat export if asked).
    """

    measurements: Path
    entry: ManipulatorCalibration
    identification: Identification
    poses: np.ndarray
    n_failed: int
    calibration: Calibration
    written: tuple[Path, ...] = field(default_factory=tuple)


def fit(request: FitRequest) -> FitResult:
    """Identify a manipulator's model from measurements and add it to calibration.json.

    Raises
    ------
    InputError, FormatError
        Outputs that cannot be written (checked before anything is read), measurements that
        cannot be read or are too few; one line each.
    """
    r = request
    update.check_fit_outputs(r.out, r.mat, r.manipulator)
    in_run = r.source.is_dir()  # a run's file may not be a link; a file the user names may
    path = r.source / "measurements.csv" if in_run else r.source
    meas = read_measurements(path, min_poses=MIN_DESIGN_POSES, link_ok=not in_run)
    inputs = meas.extra_inputs(list(r.extra), path)
    manifest = update.manifest_beside(path)  # run.json, read once
    held = update.measured_held_joints(manifest)  # an X-Y positioner's dz
    entry, fits = calibrate_manipulator(
        r.manipulator or update.measured_device(manifest), meas.d_um, meas.p_um, r.model,
        train=r.train, select=r.select, penter=r.penter, premove=r.premove, folds=r.folds,
        seed=r.seed, extra_inputs=inputs, exclude_outliers=r.exclude_outliers, held_um=held,
    )  # fmt: skip
    calibration = update.add_manipulator(
        r.out, entry, r.cameras, {"measurements": path}, r.model, manifest, mat=r.mat
    )
    written = [r.out] if r.mat is None else [r.out, r.mat]
    return FitResult(path, calibration.manipulators[entry.name], fits[r.model], meas.pose,
                     meas.n_failed, calibration, tuple(written))  # fmt: skip


@dataclass(frozen=True)
class SolveRequest:
    """What ``microcal solve`` is asked.

    Attributes
    ----------
    calibration : Path
        calibration.json.
    position_um : sequence of float
        X, Y, Z of the target in {G}, µm.
    manipulator : str, optional
        The entry (optional when the file holds one).
    temperature : float, optional
        Ambient temperature, °C, for a model with temperature terms.
    limits : str, optional
        Soft limits ``LOW:HIGH`` per joint, µm, comma-separated.
    """

    calibration: Path
    position_um: tuple[float, ...]
    manipulator: str | None = None
    temperature: float | None = None
    limits: str | None = None


@dataclass(frozen=True)
class SolveResult:
    """The compensator's solution and the calibration entry it came from."""

    solution: Solution
    entry: ManipulatorCalibration


def solve(request: SolveRequest) -> SolveResult:
    """The joint commands that put the end-effector at a position (the compensator)."""
    m = load_calibration(request.calibration).manipulator(request.manipulator)
    values: Mapping[str, float] = (
        {}
        if request.temperature is None
        else {"temperature": parse_number(request.temperature, "--temperature")}
    )
    limits = parse_limits(request.limits) if request.limits is not None else None
    solution = solve_position(m, parse_position(list(request.position_um)), values,
                              limits_um=limits)  # fmt: skip
    return SolveResult(solution, m)
