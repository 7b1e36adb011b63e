"""Identification of a manipulator's kinematic model from measurements (thesis 4.3, 5.2).

Fits the matrix or the polynomial model, validates it the thesis's way (fit on the first
poses, validate on the rest) or by k-fold cross-validation, and packs the result for
calibration.json.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from .._validation import FloatArray, as_array
from ..errors import DegenerateDataError, InputError
from ..kinematics import (
    CrossValidation,
    KinematicModel,
    Validation,
    cross_validate,
    fit_matrix_model,
    fit_polynomial_model,
    validate_split,
)
from ..kinematics.extra_inputs import (
    APPROACH_INPUTS,
    extra_input,
    identifiability_problem,
    is_approach,
)
from ..kinematics.families import FAMILIES, choose_family, fit_family
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..kinematics.models import check_inputs_move
from ..kinematics.terms import JOINTS
from ..thesis.experiment import SPLIT

__all__ = ["Identification", "calibrate_manipulator", "default_train", "identify"]


def default_train(n: int) -> int:
    """Poses used for fitting by default: the thesis's 110 / 170 share of ``n``."""
    return max(1, min(n - 1, round(n * SPLIT[0] / SPLIT[1])))


@dataclass(frozen=True)
class Identification:
    """An identified model and how well it predicts poses it was not fitted to."""

    model: KinematicModel
    validation: dict[str, object]  # the calibration.json "validation" object
    split: Validation | None
    cross_validation: CrossValidation | None
    inputs: FloatArray  # (N, k) used
    positions_um: FloatArray  # (N, 3) used
    #: Rows the model misses by more than :data:`OUTLIER_Z` robust standard deviations on
    #: some axis: (row, distance from the model µm, robust z), worst first.
    outliers: tuple[tuple[int, float, float], ...] = ()
    #: Rows of the data given that were left out as outliers (``exclude_outliers``).
    excluded: tuple[int, ...] = ()


#: A pose the model misses by more than this many robust standard deviations (1.4826 x the
#: median absolute deviation of the residuals, per axis) is an outlier: a mis-measured pose,
#: a frame of another pose. Gaussian residuals pass it once in about 10^8 poses.
OUTLIER_Z = 6.0


def find_outliers(
    model: KinematicModel, inputs: FloatArray, positions_um: FloatArray, z: float = OUTLIER_Z
) -> tuple[tuple[int, float, float], ...]:
    """Rows whose residual from ``model`` exceeds ``z`` robust standard deviations on an axis.

    Parameters
    ----------
    inputs : (N, k) float
    positions_um : (N, 3) float

    Returns
    -------
    tuple of (row, distance_um, robust_z), worst first
    """
    r = positions_um - model.predict_um(inputs)
    centred = r - np.median(r, axis=0)
    sigma = np.maximum(1.4826 * np.median(np.abs(centred), axis=0), 1e-3)  # a 1 nm floor
    score = np.max(np.abs(centred) / sigma, axis=1)
    rows = np.flatnonzero(score > z)
    rows = rows[np.argsort(-score[rows])]
    distance = np.linalg.norm(r, axis=1)
    return tuple((int(i), float(distance[i]), float(score[i])) for i in rows)


def _checked_held(held_um: Mapping[str, float] | None, u: FloatArray) -> dict[str, float]:
    held: dict[str, float] = {}
    for name, value in (held_um or {}).items():
        if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
            raise InputError(f"held joints: expected a value in µm for {name}, got {value!r}")
        held[str(name)] = float(value)
    for name, value in held.items():
        if name not in JOINTS:
            raise InputError(f"held joints: expected names among {list(JOINTS)}, got {name!r}")
        k = JOINTS.index(name)
        if u.shape[0] and not np.all(u[:, k] == value):
            raise DegenerateDataError(
                f"joint {name} is held at {value:g} µm, but its commands go from "
                f"{u[:, k].min():g} to {u[:, k].max():g} µm; these poses are not of that device"
            )
    if len(held) == len(JOINTS):
        raise InputError("held joints: every joint is held; none moves")
    check_inputs_move(u[:, :3], JOINTS, [j for j in JOINTS if j not in held])
    return held


def identify(
    d_um: FloatArray,
    p_um: FloatArray,
    model: Literal["matrix", "polynomial"] = "polynomial",
    *,
    select: Literal["stepwise", "all"] = "stepwise",
    penter: float = 0.05,
    premove: float = 0.10,
    train: int | None = None,
    folds: int | None = None,
    seed: int = 0,
    extra_inputs: Mapping[str, FloatArray] | None = None,
    family: str = "quadratic",
    held_um: Mapping[str, float] | None = None,
) -> Identification:
    """Fit and validate a kinematic model.

    Parameters
    ----------
    d_um : (N, 3) float
        Joint commands, µm.
    p_um : (N, 3) float
        Measured positions in {G}, µm.
    model : {"matrix", "polynomial"}
    select : {"stepwise", "all"}
        For the polynomial model: stepwise selection (default) or every term.
    train : int, optional
        Fit on the first ``train`` poses, validate on the rest (default: the thesis's share).
        The model returned is the one fitted on those poses.
    folds : int, optional
        Also cross-validate the whole procedure (selection included) with this many folds;
        its figures and how often each term was selected join the validation.
    extra_inputs : mapping of name -> (N,) float, optional
        Values of extra inputs of the registry (:mod:`microcal.kinematics.extra_inputs`),
        by name; their terms (for the temperature T and T², Eq 4.10) join the polynomial
        model.
    family : str
        The polynomial model's candidate terms (:data:`~microcal.kinematics.families.FAMILIES`):
        ``quadratic`` (the thesis's, default), a richer one, or ``auto``: the family whose
        fit predicts held-out fitting poses best (k-fold, before the validation poses are
        touched); the choice and every candidate's score join the model's ``selection``.
    held_um : mapping of joint -> value, optional
        Joints the device holds still (``dz`` of an X-Y positioner, as its run.json says):
        every command must give each its value; the model leaves it out, and its approach
        direction with it.
    """
    u = np.asarray(d_um, dtype=np.float64)
    positions = np.asarray(p_um, dtype=np.float64)
    held = _checked_held(held_um, u)
    moving = [k for k, j in enumerate(JOINTS) if j not in held]
    extra: dict[str, int] = {}
    for name, values in (extra_inputs or {}).items():
        if is_approach(name) and JOINTS[APPROACH_INPUTS.index(name)] in held:
            continue  # the direction of a joint that never moves
        entry = extra_input(name)
        column = as_array(values, entry.column, (u.shape[0],))
        problem = identifiability_problem(name, column, u[:, moving])
        if problem:
            raise DegenerateDataError(f"extra input: {problem}")
        u = np.column_stack([u, column])
        extra[entry.symbol] = entry.degree
    if model == "matrix" and extra:
        raise InputError(f"extra inputs {sorted(extra_inputs or {})} need the polynomial model")
    if family != "auto" and family not in FAMILIES:
        raise InputError(f"family: expected one of {[*FAMILIES, 'auto']}, got {family!r}")
    n = u.shape[0]
    n_fit = default_train(n) if train is None else train
    if n - n_fit < 1 or n_fit < 1:
        raise DegenerateDataError(
            f"train: expected between 1 and {n - 1} poses for fitting ({n} usable), got {n_fit}"
        )
    inputs = ("dx", "dy", "dz", *extra)
    joint_range = np.column_stack([u[:, :3].min(axis=0), u[:, :3].max(axis=0)])
    chosen = None
    if model == "polynomial" and family == "auto":
        chosen = choose_family(
            u[:n_fit], positions[:n_fit], inputs, extra, joint_range, seed=seed, held_um=held
        )

    def fit(u_fit: FloatArray, p_fit: FloatArray) -> KinematicModel:
        if model == "matrix":
            return fit_matrix_model(u_fit, p_fit, held)
        if model != "polynomial":
            raise InputError(f"model: expected 'matrix' or 'polynomial', got {model!r}")
        if family == "quadratic" or (select == "all" and chosen is None):
            return fit_polynomial_model(
                u_fit, p_fit, select=select, penter=penter, premove=premove, extra=extra,
                held_um=held,
            )  # fmt: skip
        fam = chosen.family if chosen is not None else FAMILIES[family]
        fitted = fit_family(u_fit, p_fit, fam, inputs, extra, joint_range, held)
        if chosen is None:
            return fitted
        return dataclasses.replace(fitted, selection={**fitted.selection, **chosen.as_dict()})

    val = validate_split(fit, u, positions, n_fit)
    validation: dict[str, object] = {
        "method": f"first {n_fit} fit, last {n - n_fit} validate",
        **val.as_dict(),
    }
    cv = None
    if folds is not None:
        cv = cross_validate(fit, u, positions, folds, seed)
        validation["cross_validation"] = cv.as_dict()
    found = find_outliers(val.model, u, positions)
    return Identification(val.model, validation, val, cv, u, positions, found)


def calibrate_manipulator(
    name: str,
    d_um: FloatArray,
    p_um: FloatArray,
    model: Literal["matrix", "polynomial"] = "polynomial",
    *,
    train: int | None = None,
    exclude_outliers: bool = False,
    **options: Any,
) -> tuple[ManipulatorCalibration, dict[str, Identification]]:
    """The whole calibration of one manipulator: its model, validation and what goes with it.

    Identifies ``model`` as :func:`identify` does (``options`` are its keywords); with
    ``exclude_outliers`` the poses it finds to be outliers are left out and it is fitted
    again (the result lists them in ``excluded``). A polynomial
    model is joined by the matrix model fitted on the same poses (for the matrix compensator,
    Eq 4.16), and the range of the joints the model was identified on is recorded.

    Returns
    -------
    calibration : ManipulatorCalibration
        What calibration.json holds for this manipulator.
    identifications : dict of kind -> Identification
        The fits themselves (the data used, the split and cross-validation): ``model``'s,
        and for a polynomial model also the matrix model's.
    """
    result = identify(d_um, p_um, model, train=train, **options)
    if exclude_outliers and result.outliers:
        keep = np.ones(len(result.inputs), dtype=bool)
        excluded = tuple(sorted(row for row, _, _ in result.outliers))
        keep[list(excluded)] = False
        extra_inputs = options.get("extra_inputs") or {}
        options["extra_inputs"] = {k: np.asarray(v)[keep] for k, v in extra_inputs.items()}
        d_um, p_um = np.asarray(d_um)[keep], np.asarray(p_um)[keep]
        refit = identify(d_um, p_um, model, train=train, **options)
        result = dataclasses.replace(refit, outliers=result.outliers, excluded=excluded)
    d = np.asarray(d_um, dtype=np.float64)
    extra: dict[str, object] = {
        "joint_range_um": np.column_stack([d.min(axis=0), d.max(axis=0)]).tolist()
    }
    fits: dict[str, Identification] = {model: result}
    if model == "polynomial":
        matrix = identify(d_um, p_um, "matrix", train=train, held_um=options.get("held_um"))
        extra["matrix_model"] = matrix.model.to_dict()
        extra["matrix_validation"] = matrix.validation
        fits = {"matrix": matrix, "polynomial": result}
    return ManipulatorCalibration(name, result.model, result.validation, extra), fits
