"""``microcal fit`` (identify a manipulator's model) and ``microcal solve`` (its compensator)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import InputError
from ..formats.calibration_file import Calibration, load_calibration
from ..formats.measurements import Measurements, read_measurements
from ..kinematics.extra_inputs import (
    APPROACH_INPUTS,
    expand_names,
    extra_input,
    identifiability_problem,
    is_approach,
)
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
    approach : bool, optional
        Model the joints' approach directions (terms ``sx, sy, sz``: the reversal error).
        None (the default): when the measurements recorded them and each joint arrived from
        both sides often enough to identify its term, as the demo does; False: never.
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
    approach: bool | None = None


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
    notes: tuple[str, ...] = ()
    """What was chosen by default (``note: ...``) and warnings about the measurements fitted
    (``warning: ...``), one line each."""


def extras_to_fit(
    names: tuple[str, ...], approach: bool | None, meas: Measurements, model: str = "polynomial"
) -> tuple[list[str], tuple[str, ...]]:
    """The extra inputs to fit and the note that says what was chosen by default.

    ``approach`` None adds each joint's approach direction that the measurements recorded at
    every pose and that can be identified from them (both signs often enough, not following
    the joints); True adds all three (refused if not recorded); False none. The matrix model
    (``model``) takes no extra input, so None adds none to it.

    Raises
    ------
    InputError
        ``--no-approach`` with ``--extra approach...``.
    """
    chosen = expand_names(list(names))
    given = [n for n in chosen if is_approach(n)]
    if approach is False:
        if given:
            raise InputError("--no-approach and --extra approach: choose one")
        return chosen, ()
    if approach is True:
        return chosen + [n for n in APPROACH_INPUTS if n not in given], ()
    if given or model != "polynomial":
        return chosen, ()
    found = []
    moving = meas.d_um[:, np.ptp(meas.d_um, axis=0) > 0]  # the joints that move
    for name in APPROACH_INPUTS:
        values = meas.extra.get(name)
        if (values is not None and np.all(np.isfinite(values))
                and identifiability_problem(name, values, moving) is None):  # fmt: skip
            found.append(name)
    if not found:
        return chosen, ()
    symbols = ", ".join(extra_input(n).symbol for n in found)
    note = (f"note: fitting the direction terms {symbols} (reversal error), as the run "
            "recorded each pose's approach direction; --no-approach leaves them out")  # fmt: skip
    return chosen + found, (note,)


#: Measured positions spanning this many times more than the joint commands (µm for µm on a
#: micromanipulator) mean joint commands written in another unit, millimetres most likely.
_JOINT_UNIT_RATIO = 100.0


def _check_joint_units(meas: Measurements, path: Path) -> None:
    """Refuse joint commands whose range is far below the measured positions' range.

    A micromanipulator moves its end-effector by about as much as its joints move (µm for
    µm), so the two ranges are of one order; joints written in millimetres span a thousand
    times less. Joints that do not move at all are left to the fit to refuse.

    Raises
    ------
    InputError
        Naming the file, both ranges and the unit expected.
    """
    span_d = float(np.max(np.ptp(meas.d_um, axis=0)))
    span_p = float(np.max(np.ptp(meas.p_um, axis=0)))
    if span_d > 0 and span_p > _JOINT_UNIT_RATIO * span_d:
        raise InputError(
            f"{path}: the joint commands span {span_d:.3g} but the measured positions "
            f"{span_p:.3g} µm; dx_um, dy_um, dz_um are micrometres (a micromanipulator moves "
            f"about as far as its joints): if they are millimetres, multiply them by 1000"
        )


def _repeated_rows_note(meas: Measurements, path: Path) -> str | None:
    """A warning when rows repeat another row's joint commands and measured position
    exactly: copies, since no two measurements agree to the last digit; each weights the fit
    as a pose of its own."""
    rows = np.hstack([meas.d_um, meas.p_um])
    _, first = np.unique(rows, axis=0, return_index=True)
    copies = np.setdiff1d(np.arange(len(rows)), first)
    if copies.size == 0:
        return None
    poses = ", ".join(str(int(v)) for v in meas.pose[copies][:5]) + (
        ", ..." if copies.size > 5 else ""
    )
    return (
        f"{path}: {copies.size} rows repeat another row's joint commands and measured "
        f"position exactly (poses {poses}); each copy weights the fit as one more pose: "
        f"remove the copies"
    )


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
    if r.source.is_dir() and (r.source / "adaptive.json").is_file():
        return _fit_adaptive(r)
    in_run = r.source.is_dir()  # a run's file may not be a link; a file the user names may
    path = r.source / "measurements.csv" if in_run else r.source
    meas = read_measurements(path, min_poses=MIN_DESIGN_POSES, link_ok=not in_run)
    names, notes = extras_to_fit(r.extra, r.approach, meas, r.model)
    inputs = meas.extra_inputs(names, path)
    _check_joint_units(meas, path)
    repeated = _repeated_rows_note(meas, path)
    if repeated is not None:
        notes = (*notes, f"warning: {repeated}")
    manifest = update.manifest_beside(path)  # run.json, read once
    held = update.measured_held_joints(manifest)  # an X-Y positioner's dz
    entry, fits = calibrate_manipulator(
        r.manipulator or update.measured_device(manifest), meas.d_um, meas.p_um, r.model,
        train=r.train, select=r.select, penter=r.penter, premove=r.premove, folds=r.folds,
        seed=r.seed, extra_inputs=inputs, exclude_outliers=r.exclude_outliers, held_um=held,
    )  # fmt: skip
    if in_run:
        entry = _with_one_camera_frame(entry, r.source)
    calibration = update.add_manipulator(
        r.out, entry, r.cameras, {"measurements": path}, r.model, manifest, mat=r.mat
    )
    written = [r.out] if r.mat is None else [r.out, r.mat]
    return FitResult(path, calibration.manipulators[entry.name], fits[r.model], meas.pose,
                     meas.n_failed, calibration, tuple(written), notes)  # fmt: skip


def _with_one_camera_frame(entry: ManipulatorCalibration, run: Path) -> ManipulatorCalibration:
    """A one-camera run's entry with where its joints are counted from (``joint_origin_um``)
    and the working volume in {M} it filled (``working_volume_um``: low and high corners), as
    one_camera.json records them, for goto, evaluate and check on the rig; any other run's
    entry as it is."""
    from ..formats.one_camera_run import is_one_camera_run, read_one_camera_setup

    if not is_one_camera_run(run):
        return entry
    setup = read_one_camera_setup(run)
    centre = np.asarray(setup["volume_centre_um"], dtype=np.float64)
    half = np.asarray(setup["volume_half_um"], dtype=np.float64)
    extra = {**entry.extra, "joint_origin_um": setup["joint_origin_um"],
             "working_volume_um": [(centre - half).tolist(), (centre + half).tolist()]}  # fmt: skip
    return dataclasses.replace(entry, extra=extra)


def _fit_adaptive(r: FitRequest) -> FitResult:
    """An adaptive run (``microcal acquire --design adaptive``) fitted whole, as its design
    fits it (:mod:`~microcal.workflows.adaptive_fit`)."""
    from .adaptive_fit import (
        MEASUREMENTS,
        check_adaptive_fit_options,
        fit_adaptive_run,
        predicted_line,
    )

    check_adaptive_fit_options(r)
    calibration, entry, ident, poses, n_failed = fit_adaptive_run(r.source, r.out, r.cameras,
                                                                  r.manipulator)  # fmt: skip
    note = (f"note: an adaptive run: its design's smooth model fitted on all {len(poses)} "
            f"poses; {predicted_line(entry)}")  # fmt: skip
    return FitResult(r.source / MEASUREMENTS, entry, ident, poses, n_failed, calibration,
                     (r.out,), (note,))  # fmt: skip


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
