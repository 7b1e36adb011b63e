"""``calibration.json``: cameras and manipulator models, versioned, validated on load.

The keys that other tools read are listed in DESIGN.md and docs/formats.md; more keys may be
added freely. No pickle: plain JSON, lengths in µm.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike
from pydantic import BaseModel, ConfigDict, ValidationError

from .._validation import FloatArray
from .._version import __version__
from ..errors import DegenerateDataError, FormatError, InputError
from ..kinematics.compensators import Compensator
from ..kinematics.models import KinematicModel
from .atomic import write_atomic, write_text_atomic
from .json_file import read_versioned_json, validation_message

__all__ = [
    "CALIBRATION_FORMAT",
    "Calibration",
    "ManipulatorCalibration",
    "export_mat",
    "load_calibration",
    "provenance",
    "sha256_file",
    "write_calibration",
]

CALIBRATION_FORMAT = "microcal.calibration/1"


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


class _ModelSchema(_Open):
    kind: Literal["matrix", "polynomial"]
    inputs: list[str]
    joints: list[str]
    terms: list[str]
    selected: list[list[bool]]
    coefficients: list[list[float]]
    covariance: list[list[list[float]]]


class _ValidationSchema(_Open):
    n_fit: int
    n_validate: int
    mean_um: float
    std_um: float
    max_um: float
    rms_um: float


class _ManipulatorSchema(_Open):
    model: _ModelSchema
    validation: _ValidationSchema | None = None


class _CalibrationSchema(_Open):
    format: Literal["microcal.calibration/1"]
    cameras: dict[str, Any] = {}
    manipulators: dict[str, _ManipulatorSchema]
    provenance: dict[str, Any] = {}


@dataclass(frozen=True)
class ManipulatorCalibration:
    """The calibration of one manipulator: its model and the figures that validate it."""

    name: str
    model: KinematicModel
    validation: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def predict_um(self, u: ArrayLike) -> FloatArray:
        """Position in {G} (µm) for joint values (and further inputs), (N, 3)."""
        return self.model.predict_um(u)

    @property
    def matrix_model(self) -> KinematicModel | None:
        """The matrix model stored beside a polynomial one (for the matrix compensator)."""
        data = self.extra.get("matrix_model")
        if data is None:
            return self.model if self.model.kind == "matrix" else None
        return KinematicModel.from_dict(data)

    @cached_property
    def compensator(self) -> Compensator:
        """The model prepared for inversion (built on first use)."""
        return Compensator(self.model)

    @property
    def joint_range_um(self) -> FloatArray | None:
        """(3, 2) range of the joints in the identification data, if recorded."""
        rng = self.extra.get("joint_range_um")
        return None if rng is None else np.asarray(rng, dtype=np.float64)

    def joints_for(
        self,
        p_um: ArrayLike,
        *,
        extra: ArrayLike | None = None,
        limits_um: ArrayLike | None = None,
    ) -> FloatArray:
        """Joint commands (µm) that put the end-effector at ``p_um`` in {G}: the compensator.

        The matrix model is inverted exactly (Eq 4.16); a polynomial model is solved by the
        optimal compensator (Eq 4.17-4.19).

        Parameters
        ----------
        p_um : (N, 3) or (3,) float
            Desired positions in {G}, µm.
        extra : float or (N, e) float, optional
            Values of the model's extra inputs (the temperature in °C), if it has any.
        limits_um : (3, 2) float, optional
            Soft limits per joint; a target outside raises LimitError and nothing is returned.

        Returns
        -------
        d_um : (N, 3) float

        Raises
        ------
        DegenerateDataError
            A target for which the model has no solution (it did not converge).
        LimitError
            A target that needs joints outside ``limits_um``.
        """
        comp = self.compensator
        if limits_um is not None:
            comp = Compensator(self.model, limits_um)
        if self.model.kind == "matrix":
            return comp.linear(p_um, extra=extra)
        result = comp.solve(p_um, extra=extra)
        if not result.converged.all():
            bad = int(np.flatnonzero(~result.converged)[0])
            raise DegenerateDataError(
                f"{int((~result.converged).sum())} target(s) have no solution of the model "
                f"(first: row {bad}, residual {result.residual_um[bad]:.3g} µm); "
                f"is the target inside the calibrated workspace?"
            )
        return result.d_um

    def to_dict(self) -> dict[str, Any]:
        """The manipulator's object in calibration.json."""
        return {**self.extra, "model": self.model.to_dict(), "validation": self.validation}


@dataclass(frozen=True)
class Calibration:
    """A whole calibration file: cameras, manipulators and provenance."""

    manipulators: dict[str, ManipulatorCalibration]
    cameras: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    path: Path | None = None

    def manipulator(self, name: str | None = None) -> ManipulatorCalibration:
        """One manipulator's calibration; ``name`` may be omitted when there is only one."""
        if name is None:
            if len(self.manipulators) == 1:
                return next(iter(self.manipulators.values()))
            raise InputError(
                f"manipulator: this calibration has {sorted(self.manipulators)}; name one"
            )
        try:
            return self.manipulators[name]
        except KeyError:
            where = f" in {self.path}" if self.path else ""
            raise InputError(
                f"manipulator {name!r} is not calibrated{where}; it has {sorted(self.manipulators)}"
            ) from None

    def to_dict(self) -> dict[str, Any]:
        """The JSON object of calibration.json."""
        return {
            "format": CALIBRATION_FORMAT,
            # the cameras' models and figures; their per-point residuals stay in cameras.json
            "cameras": {
                name: {k: v for k, v in cam.items() if k != "residuals_px"}
                if isinstance(cam, dict)
                else cam
                for name, cam in self.cameras.items()
            },
            "manipulators": {n: m.to_dict() for n, m in self.manipulators.items()},
            "provenance": self.provenance,
        }


def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def provenance(
    inputs: Mapping[str, str | os.PathLike[str]] | None = None, **extra: Any
) -> dict[str, Any]:
    """Software version, UTC time and the SHA-256 of each input file."""
    return {
        "software": f"microcal {__version__}",
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "inputs": {
            name: {"path": str(p), "sha256": sha256_file(p)} for name, p in (inputs or {}).items()
        },
        **extra,
    }


def write_calibration(path: str | os.PathLike[str], calibration: Calibration) -> Path:
    """Write calibration.json atomically (never a half-written file)."""
    try:
        text = json.dumps(calibration.to_dict(), indent=1, allow_nan=False)
    except ValueError as exc:
        raise FormatError(f"calibration: refusing to write non-finite numbers ({exc})") from None
    return write_text_atomic(path, text + "\n")


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    """Read and validate calibration.json.

    Raises
    ------
    FormatError
        Missing file, not JSON, unknown format version, or any key of the wrong kind or
        shape; the message names the key.
    """
    p = Path(path)
    raw = read_versioned_json(p, (CALIBRATION_FORMAT,))
    try:
        schema = _CalibrationSchema.model_validate(raw)
    except ValidationError as exc:
        raise FormatError(f"{p}: {validation_message(exc)}") from None
    manipulators = {}
    for name in schema.manipulators:
        data = raw["manipulators"][name]
        try:
            model = KinematicModel.from_dict(data["model"])
        except FormatError as exc:
            raise FormatError(f"{p}: manipulators.{name}.{exc}") from None
        extra = {k: v for k, v in data.items() if k not in ("model", "validation")}
        validation = data.get("validation") or {}
        manipulators[name] = ManipulatorCalibration(name, model, validation, extra)
    return Calibration(manipulators, raw.get("cameras", {}), raw.get("provenance", {}), p)


def export_mat(path: str | os.PathLike[str], calibration: Calibration) -> Path:
    """Write the models as a MATLAB .mat file (one struct per manipulator), atomically.

    Each struct has ``kind``, ``inputs``, ``terms`` (cell arrays of names), ``coefficients``
    (3 x m, rows x, y, z in µm), ``selected`` (3 x m logical), ``covariance`` (3 x m x m) and
    the validation figures.
    """
    import scipy.io

    data: dict[str, Any] = {}
    for name, m in calibration.manipulators.items():
        key = (
            name if name.isidentifier() else "m_" + "".join(c if c.isalnum() else "_" for c in name)
        )
        data[key] = {
            "kind": m.model.kind,
            "inputs": np.array(m.model.inputs, dtype=object),
            "terms": np.array([t.name for t in m.model.terms], dtype=object),
            "coefficients": m.model.coefficients,
            "selected": m.model.selected,
            "covariance": m.model.covariance,
            "validation": {k: v for k, v in m.validation.items() if isinstance(v, int | float)},
        }

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            scipy.io.savemat(fh, data, long_field_names=True)

    return write_atomic(path, write)
