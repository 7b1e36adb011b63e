"""``cameras.json``: calibrated cameras in one {V}, versioned, validated on load.

Each camera names its model's kind in ``"model"`` (written always). Files written before the
key existed hold pinhole cameras and are read as such. :data:`CAMERA_LOADERS` maps each kind
to the function that builds its camera model from the camera's JSON object: a new kind of
camera model adds one entry there.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TypedDict

import numpy as np
from pydantic import Field, ValidationError
from pydantic import JsonValue as AnyJson

from .._validation import name_problem
from ..errors import FormatError, InputError
from ..geometry.affine_camera import AffineCamera
from ..geometry.camera_kinds import AnyCamera
from ..geometry.camera_model import CameraModel
from ..json_value import JsonValue, checked_json
from ..vision.calibration_diagnostics import CameraDiagnostics
from ..vision.stereo_calibration import StereoCalibration
from .atomic import write_text_atomic
from .json_file import FileSchema, read_versioned_json, validation_message

__all__ = [
    "CAMERAS_FORMAT",
    "CAMERA_LOADERS",
    "DEFAULT_CAMERA_MODEL",
    "CameraLoader",
    "CameraRecord",
    "CamerasJson",
    "CamerasRecord",
    "cameras_to_dict",
    "load_cameras",
    "models_from_dict",
    "read_cameras",
    "save_stereo_calibration",
    "write_cameras",
]

CAMERAS_FORMAT = "microcal.cameras/1"
#: The kind of a camera without a ``"model"`` key (files written before the key existed).
DEFAULT_CAMERA_MODEL = "pinhole"

#: Builds a camera model from its JSON object and its name. Raises pydantic's
#: ``ValidationError`` for a malformed object or ``InputError`` for invalid values.
CameraLoader = Callable[[Mapping[str, object], str], AnyCamera]


class _PinholeCamera(FileSchema):
    image_size_px: tuple[int, int]
    K: list[list[float]]
    dist: list[float]
    R: list[list[float]]
    t_um: list[float]
    projection_sigma_px: float = 0.0


class _Cameras(FileSchema):
    format: str
    cameras: dict[str, dict[str, AnyJson]]


def _load_pinhole(cam: Mapping[str, object], name: str) -> CameraModel:
    c = _PinholeCamera.model_validate(cam)
    K, dist, R, t_um = (np.array(v) for v in (c.K, c.dist, c.R, c.t_um))
    return CameraModel(K, dist, R, t_um, c.image_size_px, name, c.projection_sigma_px)


def _load_affine(cam: Mapping[str, object], name: str) -> AffineCamera:
    """An affine camera has the pinhole's keys: K holds the magnification in px/µm (see
    :class:`~microcal.geometry.affine_camera.AffineCamera`)."""
    c = _PinholeCamera.model_validate(cam)
    K, dist, R, t_um = (np.array(v) for v in (c.K, c.dist, c.R, c.t_um))
    return AffineCamera(K, dist, R, t_um, c.image_size_px, name, c.projection_sigma_px)


#: Camera model kind (cameras.json's ``"model"``) -> its loader.
CAMERA_LOADERS: dict[str, CameraLoader] = {"pinhole": _load_pinhole, "affine": _load_affine}


class CamerasJson(TypedDict):
    """The JSON object of cameras.json as microcal writes it."""

    format: str
    cameras: dict[str, dict[str, JsonValue]]
    stereo: dict[str, JsonValue]
    provenance: Mapping[str, JsonValue]


def cameras_to_dict(cal: StereoCalibration, provenance: Mapping[str, JsonValue]) -> CamerasJson:
    """The JSON object of cameras.json."""
    cameras: dict[str, dict[str, JsonValue]] = {}
    for name, c in cal.cameras.items():
        m = c.model
        cameras[name] = {
            "model": m.kind,
            "image_size_px": list(m.image_size_px),
            "K": m.K.tolist(),
            "dist": m.dist.tolist(),
            "R": m.R.tolist(),
            "t_um": m.t_um.tolist(),
            "projection_sigma_px": m.projection_sigma_px,
            "rms_px": c.rms_px,
            "views_used": c.views_used,
            "views_rejected": checked_json(c.views_rejected),
            "per_view_rms_px": c.per_view_rms_px,
            "std": c.std,
            "residuals_px": {view: np.round(r, 4).tolist() for view, r in c.residuals_px.items()},
        }
        if c.lens_model:
            cameras[name]["lens_model"] = checked_json(c.lens_model, "lens_model")
        if c.model_choice:
            cameras[name]["model_choice"] = checked_json(c.model_choice, "model_choice")
        if c.diagnostics is not None:
            cameras[name]["diagnostics"] = _diagnostics_to_dict(c.diagnostics)
    return {
        "format": CAMERAS_FORMAT,
        "cameras": cameras,
        "stereo": {
            "method": cal.method,
            "rms_px": cal.rms_px,
            "baseline_um": _finite(cal.baseline_um),
            "angle_deg": cal.angle_deg,
            "turned_views": checked_json(cal.turned_views, "turned_views"),
            "views_rejected": checked_json(cal.views_rejected, "views_rejected"),
            "notes": cal.notes,
            **(
                {"consistency": checked_json(cal.consistency, "consistency")}
                if cal.consistency
                else {}
            ),
        },
        "provenance": provenance,
    }


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _diagnostics_to_dict(d: CameraDiagnostics) -> dict[str, JsonValue]:
    half = d.split_half
    return {
        "std_intrinsics": {k: _finite(v) for k, v in d.std_intrinsics.items()},
        "uncertainty_px": {k: _finite(v) for k, v in d.uncertainty_px.items()},
        "uncertainty_map_px": [
            [_finite(round(float(v), 4)) for v in row] for row in d.uncertainty_map_px
        ],
        "split_half": None
        if half is None
        else {
            "rms_diff_px": half.rms_diff_px,
            "max_diff_px": half.max_diff_px,
            "observed_rms_diff_px": half.observed_rms_diff_px,
            "predicted_px": half.predicted_px,
            "ratio": _finite(half.ratio),
            "flags": half.flags,
        },
        "coverage": checked_json(d.coverage, "coverage"),
        "verdict": d.verdict,
    }


def write_cameras(path: str | os.PathLike[str], data: CamerasJson) -> Path:
    """Write cameras.json atomically."""
    return write_text_atomic(path, json.dumps(data, indent=1, allow_nan=False) + "\n")


def save_stereo_calibration(
    path: str | os.PathLike[str],
    cal: StereoCalibration,
    images: Mapping[str, list[Path]],
    displacements: Path | None,
    target_spec: str,
) -> Path:
    """Write a stereo calibration to cameras.json with its provenance (each image's hash)."""
    from .provenance import provenance

    inputs: dict[str, Path] = {f"{cam}/{f.name}": f for cam, fs in images.items() for f in fs}
    if displacements is not None:
        inputs["displacements"] = displacements
    prov = provenance(inputs, command="stereo-calibrate", target=target_spec)
    return write_cameras(path, cameras_to_dict(cal, prov))


def models_from_dict(data: Mapping[str, object], where: str = "cameras") -> dict[str, AnyCamera]:
    """Camera models from a cameras.json object (or the ``cameras`` part of calibration.json).

    Each camera's ``"model"`` (``"pinhole"`` when absent) picks its loader in
    :data:`CAMERA_LOADERS`.

    Raises
    ------
    FormatError
        The object does not validate, a camera names a model kind not in
        :data:`CAMERA_LOADERS`, or its values do not make a camera; the message names
        ``where`` and the camera.
    """
    return _models(_parse(data, where), where)


def _parse(data: Mapping[str, object], where: str) -> _Cameras:
    try:
        return _Cameras.model_validate(data)
    except ValidationError as exc:
        raise FormatError(f"{where}: {validation_message(exc)}") from None


def _models(parsed: _Cameras, where: str) -> dict[str, AnyCamera]:
    models: dict[str, AnyCamera] = {}
    for name in parsed.cameras:  # a camera's name becomes a file name (images/NAME_0001.tiff)
        problem = name_problem(name)
        if problem is not None:
            raise FormatError(f"{where}: cameras: {problem}")
    for name, cam in parsed.cameras.items():
        _check_uncertainties(cam, f"{where}: cameras.{name}")
        kind = cam.get("model", DEFAULT_CAMERA_MODEL)
        loader = CAMERA_LOADERS.get(kind) if isinstance(kind, str) else None
        if loader is None:
            known = ", ".join(repr(k) for k in CAMERA_LOADERS)
            raise FormatError(
                f"{where}: cameras.{name}.model: expected one of {known}, got {kind!r} "
                "(a camera model this version of microcal does not know)"
            )
        try:
            models[name] = loader(cam, name)
        except ValidationError as exc:
            raise FormatError(f"{where}: cameras.{name}.{validation_message(exc)}") from None
        except InputError as exc:
            raise FormatError(f"{where}: cameras.{name}: {exc}") from None
        except (ValueError, TypeError, OverflowError) as exc:  # arrays of ragged or odd values
            raise FormatError(f"{where}: cameras.{name}: not a camera's numbers ({exc})") from None
    try:
        _check_usable(models, where)
    except FormatError:
        raise
    except (ValueError, OverflowError, FloatingPointError) as exc:
        raise FormatError(f"{where}: cameras hold numbers no camera has ({exc})") from None
    return models


#: A camera's keys that hold standard deviations (or uncertainties), every number >= 0
#: (``projection_sigma_px`` is the camera model's own, checked as it is built).
_UNCERTAINTY_KEYS = ("std",)
_DIAGNOSTICS_UNCERTAINTY_KEYS = ("std_intrinsics", "uncertainty_px", "uncertainty_map_px")


def _check_uncertainties(cam: Mapping[str, object], where: str) -> None:
    """Refuse a standard deviation below zero in a camera's uncertainties, naming its key."""
    diagnostics = cam.get("diagnostics")
    keys = [(k, cam.get(k)) for k in _UNCERTAINTY_KEYS]
    if isinstance(diagnostics, Mapping):
        keys += [(f"diagnostics.{k}", diagnostics.get(k)) for k in _DIAGNOSTICS_UNCERTAINTY_KEYS]
    for key, value in keys:
        found = _first_negative(value, key)
        if found is not None:
            raise FormatError(
                f"{where}.{found[0]} = {found[1]:g} is a standard deviation below zero; "
                f"calibrate the cameras again (microcal stereo-calibrate)"
            )


def _first_negative(value: object, key: str) -> tuple[str, float] | None:
    """The first number below zero in a JSON value (its key path and value), or None."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int | float):
        return (key, float(value)) if value < 0 else None
    items: list[tuple[str, object]] = []
    if isinstance(value, Mapping):
        items = [(f"{key}.{k}", v) for k, v in value.items()]
    elif isinstance(value, list):
        items = [(f"{key}[{i}]", v) for i, v in enumerate(value)]
    for sub, v in items:
        found = _first_negative(v, sub)
        if found is not None:
            return found
    return None


def _check_usable(models: dict[str, AnyCamera], where: str) -> None:
    """Refuse cameras that are valid numbers but no cameras (see ``geometry.camera_checks``)."""
    from ..geometry.camera_checks import distortion_problem, same_view

    # every kind's distortion; the centre only of cameras that have one (pinhole)
    pinholes = {n: m for n, m in models.items() if isinstance(m, CameraModel)}
    # a kind registered from outside (not one of microcal's) brings its own checks
    own = {n: m for n, m in models.items() if type(m) in (CameraModel, AffineCamera)}
    for name, model in own.items():
        problem = distortion_problem(model)
        if problem is not None:
            raise FormatError(
                f"{where}: cameras.{name}: {problem}; calibrate it again, or with a simpler "
                f"--lens-model"
            )
    pair = same_view(pinholes)
    if pair is not None:
        raise FormatError(
            f"{where}: cameras {pair[0]} and {pair[1]} see from one centre (the same camera "
            f"twice?); measuring depth needs two views from different places"
        )


def read_cameras(
    path: str | os.PathLike[str], *, link_ok: bool = True
) -> tuple[dict[str, dict[str, AnyJson]], dict[str, AnyCamera]]:
    """The ``cameras`` object of cameras.json (or of a calibration.json) and its models.

    ``link_ok``: ``path`` may be a symbolic link to the file (one the user named); False for
    a file a run directory holds (:mod:`.safe_open`).

    Raises
    ------
    FormatError
        Missing, not JSON, another format, no cameras, or a camera that does not validate.
    """
    p = Path(path)
    raw = read_versioned_json(
        p,
        (CAMERAS_FORMAT, "microcal.calibration/1"),
        " (run 'microcal stereo-calibrate' first)",
        link_ok=link_ok,
    )
    if not raw.get("cameras"):
        raise FormatError(f"{p}: holds no cameras")
    parsed = _parse({"format": CAMERAS_FORMAT, "cameras": raw["cameras"]}, str(p))
    return parsed.cameras, _models(parsed, str(p))


def load_cameras(path: str | os.PathLike[str]) -> dict[str, AnyCamera]:
    """Read cameras.json (or a calibration.json that holds cameras)."""
    return read_cameras(path)[1]


# --- what the report reads of cameras.json ------------------------------------------------
class RejectedView(FileSchema):
    """A view a calibration left out: its image and why."""

    image: str = ""
    reason: str = ""


class LensCandidate(FileSchema):
    """A lens model a calibration tried: its free terms and training and held-out RMS."""

    name: str = ""
    n_free: int | None = None
    train_rms_px: float | None = None
    held_out_rms_px: float | None = None


class LensModelRecord(FileSchema):
    """``cameras.NAME.lens_model``: the lens model chosen, why, and the candidates."""

    name: str = ""
    reason: str = ""
    candidates: list[LensCandidate] = Field(default_factory=list)


class SplitHalfRecord(FileSchema):
    """``diagnostics.split_half``: how far the calibrations of two halves of the views
    disagree over the image, px."""

    rms_diff_px: float | None = None
    max_diff_px: float | None = None
    observed_rms_diff_px: float | None = None
    predicted_px: float | None = None
    ratio: float | None = None


class DiagnosticsRecord(FileSchema):
    """``cameras.NAME.diagnostics``: the projection's uncertainty and what limits it."""

    uncertainty_px: dict[str, float | None] = Field(default_factory=dict)
    uncertainty_map_px: list[list[float | None]] = Field(default_factory=list)
    split_half: SplitHalfRecord | None = None
    verdict: list[str] = Field(default_factory=list)


class CameraRecord(FileSchema):
    """One camera of cameras.json (or of calibration.json's ``cameras``) with its figures."""

    image_size_px: tuple[int, int]
    K: list[list[float]]
    dist: list[float] = Field(default_factory=lambda: [0.0] * 5)
    rms_px: float | None = None
    views_used: int | None = None
    views_rejected: list[RejectedView] = Field(default_factory=list)
    per_view_rms_px: dict[str, float] = Field(default_factory=dict)
    residuals_px: dict[str, list[list[float]]] = Field(default_factory=dict)
    lens_model: LensModelRecord | None = None
    diagnostics: DiagnosticsRecord | None = None


class TurnedView(FileSchema):
    """``stereo.turned_views[i]``: an image whose corner numbering was turned."""

    camera: str = ""
    image: str = ""
    turn_deg: float | None = None


class RejectedPair(FileSchema):
    """``stereo.views_rejected[i]``: a view left out of the cameras' joint refinement."""

    view: str = ""
    reason: str = ""


class StereoRecord(FileSchema):
    """``stereo``: how the cameras were calibrated together."""

    method: str = ""
    rms_px: float | None = None
    baseline_um: float | None = None
    angle_deg: float | None = None
    turned_views: list[TurnedView] = Field(default_factory=list)
    views_rejected: list[RejectedPair] = Field(default_factory=list)
    notes: list[str] = Field(default_factory=list)
    consistency: dict[str, AnyJson] = Field(default_factory=dict)


class CamerasRecord(FileSchema):
    """cameras.json as the report reads it: the cameras and their figures, the stereo
    calibration's and the provenance (any other key kept)."""

    cameras: dict[str, CameraRecord]
    stereo: StereoRecord = Field(default_factory=StereoRecord)
    provenance: dict[str, AnyJson] | None = None
