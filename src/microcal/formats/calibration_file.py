"""``calibration.json``: cameras and manipulator models, versioned, validated on load.

The keys that other tools read are listed in docs/formats.md; more keys may be
added freely. No pickle: plain JSON, lengths in µm.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import Field
from pydantic import JsonValue as AnyJson

from .._validation import name_problem
from ..errors import FormatError, InputError
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..kinematics.models import KinematicModel
from ..vision.tool_centre import ToolCentre
from .atomic import write_atomic, write_text_atomic
from .hashing import sha256_file
from .json_file import FileSchema, parse_schema, read_versioned_json

if TYPE_CHECKING:
    from ..geometry.camera_kinds import AnyCamera

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_FORMATS",
    "Calibration",
    "ManipulatorCalibration",
    "export_mat",
    "load_calibration",
    "sha256_file",
    "tool_centre_of",
    "write_calibration",
]

CALIBRATION_FORMAT = "microcal.calibration/1"
CALIBRATION_FORMATS = (CALIBRATION_FORMAT,)  # the versions this microcal reads


class _ModelSchema(FileSchema):
    kind: Literal["matrix", "polynomial"]
    inputs: list[str]
    joints: list[str]
    terms: list[str]
    selected: list[list[bool]]
    coefficients: list[list[float]]
    covariance: list[list[list[float]]]


class _ValidationSchema(FileSchema):
    n_fit: int
    n_validate: int
    mean_um: float
    std_um: float
    max_um: float
    rms_um: float


class _ToolCentreSchema(FileSchema):
    offset_um: list[float] = Field(min_length=3, max_length=3)
    cov_um2: list[list[float]] = Field(min_length=3, max_length=3)
    rms_um: float = Field(ge=0)
    poses: int = Field(ge=2)
    board_R: list[list[float]] | None = None  # noqa: N815 (R, as in the thesis)
    cov_g_um2: list[list[float]] | None = Field(default=None, min_length=3, max_length=3)


class _ManipulatorSchema(FileSchema):
    model: _ModelSchema
    validation: _ValidationSchema | None = None
    tool_centre: _ToolCentreSchema | None = None


class _CalibrationSchema(FileSchema):
    format: Literal["microcal.calibration/1"]
    cameras: dict[str, AnyJson] = Field(default_factory=dict)
    manipulators: dict[str, _ManipulatorSchema]
    provenance: dict[str, AnyJson] = Field(default_factory=dict)


@dataclass(frozen=True)
class Calibration:
    """A whole calibration file: cameras, manipulators and provenance.

    ``cameras`` are the cameras' JSON objects (as cameras.json holds them; validated by
    :meth:`camera_models`), ``provenance`` the file's provenance object.
    """

    manipulators: dict[str, ManipulatorCalibration]
    cameras: Mapping[str, object] = field(default_factory=dict)
    provenance: Mapping[str, object] = field(default_factory=dict)
    path: Path | None = None

    def camera_models(self) -> dict[str, AnyCamera]:
        """The cameras as typed models (validated when the file was loaded); {} for none."""
        if not self.cameras:
            return {}
        from .cameras_file import CAMERAS_FORMAT, models_from_dict

        where = str(self.path) if self.path else "calibration"
        return models_from_dict({"format": CAMERAS_FORMAT, "cameras": self.cameras}, where)

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

    def to_dict(self) -> dict[str, object]:
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


def write_calibration(path: str | os.PathLike[str], calibration: Calibration) -> Path:
    """Write calibration.json atomically (never a half-written file)."""
    try:
        text = json.dumps(calibration.to_dict(), indent=1, allow_nan=False)
    except ValueError as exc:
        raise FormatError(f"calibration: refusing to write non-finite numbers ({exc})") from None
    return write_text_atomic(path, text + "\n")


def load_calibration(path: str | os.PathLike[str], *, link_ok: bool = True) -> Calibration:
    """Read and validate calibration.json.

    ``link_ok``: ``path`` may be a symbolic link to the file (one the user named); False for
    a file a run directory holds (:mod:`.safe_open`).

    Raises
    ------
    FormatError
        Missing file, not JSON, unknown format version, or any key of the wrong kind or
        shape; the message names the key.
    """
    p = Path(path)
    raw = read_versioned_json(
        p,
        CALIBRATION_FORMATS,
        " (run 'microcal fit RUN --cameras CAMERAS --out FILE' first)",
        link_ok=link_ok,
    )
    schema = parse_schema(_CalibrationSchema, raw, p)
    section = raw["manipulators"]  # an object of objects: the schema has checked it
    manipulators = {}
    for name in schema.manipulators:
        problem = name_problem(name)
        if problem is not None:
            raise FormatError(f"{p}: manipulators: {problem}")
        data = section[name] if isinstance(section, dict) else None
        if not isinstance(data, dict):
            raise FormatError(f"{p}: manipulators.{name}: expected an object")
        try:
            model = KinematicModel.from_dict(data["model"])
        except FormatError as exc:
            raise FormatError(f"{p}: manipulators.{name}.{exc}") from None
        _check_validation(p, name, schema.manipulators[name].validation)
        _check_tool_centre(p, name, schema.manipulators[name].tool_centre)
        extra = {k: v for k, v in data.items() if k not in ("model", "validation")}
        validation = data.get("validation") or {}
        manipulators[name] = ManipulatorCalibration(name, model, validation, extra)
    calibration = Calibration(manipulators, schema.cameras, schema.provenance, p)
    calibration.camera_models()  # a malformed camera fails here, naming the file
    return calibration


def _check_tool_centre(path: Path, name: str, tool: _ToolCentreSchema | None) -> None:
    """Refuse a tool-centre covariance that is not 3 x 3 with variances >= 0."""
    if tool is None:
        return
    for key, cov in (("cov_um2", tool.cov_um2), ("cov_g_um2", tool.cov_g_um2)):
        if cov is not None and (any(len(row) != 3 for row in cov)
                                or any(cov[i][i] < 0 for i in range(3))):  # fmt: skip
            raise FormatError(
                f"{path}: manipulators.{name}.tool_centre.{key}: expected 3 x 3 numbers with "
                f"variances >= 0"
            )
    R = tool.board_R
    if R is not None and (
        len(R) != 3 or any(len(row) != 3 for row in R)
        or not np.allclose(np.asarray(R) @ np.asarray(R).T, np.eye(3), atol=1e-6)
    ):  # fmt: skip
        raise FormatError(
            f"{path}: manipulators.{name}.tool_centre.board_R: expected a 3 x 3 rotation"
        )


def tool_centre_of(calibration: ManipulatorCalibration) -> ToolCentre | None:
    """A manipulator's tool-centre point (the tip's offset in its board's frame), if any."""
    entry = calibration.extra.get("tool_centre")
    if not isinstance(entry, dict):
        return None
    R, cov_g = entry.get("board_R"), entry.get("cov_g_um2")
    return ToolCentre(np.asarray(entry["offset_um"], dtype=np.float64),
                      np.asarray(entry["cov_um2"], dtype=np.float64),
                      float(entry["rms_um"]), int(entry["poses"]),
                      None if R is None else np.asarray(R, dtype=np.float64),
                      None if cov_g is None else np.asarray(cov_g, dtype=np.float64))  # fmt: skip


def _check_validation(path: Path, name: str, validation: _ValidationSchema | None) -> None:
    """Refuse validation figures that cannot be: a standard deviation or RMS below zero."""
    for key in ("std_um", "rms_um"):
        value = getattr(validation, key) if validation is not None else 0.0
        if value < 0:
            raise FormatError(
                f"{path}: manipulators.{name}.validation.{key} = {value:g} is negative (a "
                f"spread is never below zero); fit the model again"
            )


def export_mat(path: str | os.PathLike[str], calibration: Calibration) -> Path:
    """Write the models as a MATLAB .mat file (one struct per manipulator), atomically.

    Each struct has ``kind``, ``inputs``, ``terms`` (cell arrays of names), ``coefficients``
    (3 x m, rows x, y, z in µm), ``selected`` (3 x m logical), ``covariance`` (3 x m x m) and
    the validation figures.
    """
    import scipy.io

    data: dict[str, dict[str, object]] = {}
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
