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
from typing import Any

import numpy as np
from pydantic import ValidationError

from ..errors import FormatError, InputError
from ..geometry.affine_camera import AffineCamera
from ..geometry.camera_kinds import AnyCamera
from ..geometry.camera_model import CameraModel
from ..vision.calibration_diagnostics import CameraDiagnostics
from ..vision.stereo_calibration import StereoCalibration
from .atomic import write_text_atomic
from .json_file import FileSchema, read_versioned_json, validation_message

__all__ = [
    "CAMERAS_FORMAT",
    "CAMERA_LOADERS",
    "DEFAULT_CAMERA_MODEL",
    "CameraLoader",
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
CameraLoader = Callable[[Mapping[str, Any], str], AnyCamera]


class _PinholeCamera(FileSchema):
    image_size_px: tuple[int, int]
    K: list[list[float]]
    dist: list[float]
    R: list[list[float]]
    t_um: list[float]
    projection_sigma_px: float = 0.0


class _Cameras(FileSchema):
    format: str
    cameras: dict[str, dict[str, Any]]


def _load_pinhole(cam: Mapping[str, Any], name: str) -> CameraModel:
    c = _PinholeCamera.model_validate(cam)
    K, dist, R, t_um = (np.array(v) for v in (c.K, c.dist, c.R, c.t_um))
    return CameraModel(K, dist, R, t_um, c.image_size_px, name, c.projection_sigma_px)


def _load_affine(cam: Mapping[str, Any], name: str) -> AffineCamera:
    """An affine camera has the pinhole's keys: K holds the magnification in px/µm (see
    :class:`~microcal.geometry.affine_camera.AffineCamera`)."""
    c = _PinholeCamera.model_validate(cam)
    K, dist, R, t_um = (np.array(v) for v in (c.K, c.dist, c.R, c.t_um))
    return AffineCamera(K, dist, R, t_um, c.image_size_px, name, c.projection_sigma_px)


#: Camera model kind (cameras.json's ``"model"``) -> its loader.
CAMERA_LOADERS: dict[str, CameraLoader] = {"pinhole": _load_pinhole, "affine": _load_affine}


def cameras_to_dict(cal: StereoCalibration, provenance: dict[str, Any]) -> dict[str, Any]:
    """The JSON object of cameras.json."""
    cameras = {}
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
            "views_rejected": c.views_rejected,
            "per_view_rms_px": c.per_view_rms_px,
            "std": c.std,
            "residuals_px": {view: np.round(r, 4).tolist() for view, r in c.residuals_px.items()},
        }
        if c.lens_model:
            cameras[name]["lens_model"] = c.lens_model
        if c.model_choice:
            cameras[name]["model_choice"] = c.model_choice
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
            "turned_views": cal.turned_views,
            "views_rejected": cal.views_rejected,
            "notes": cal.notes,
        },
        "provenance": provenance,
    }


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _diagnostics_to_dict(d: CameraDiagnostics) -> dict[str, Any]:
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
        "coverage": d.coverage,
        "verdict": d.verdict,
    }


def write_cameras(path: str | os.PathLike[str], data: dict[str, Any]) -> Path:
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


def models_from_dict(data: dict[str, Any], where: str = "cameras") -> dict[str, AnyCamera]:
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
    try:
        parsed = _Cameras.model_validate(data)
    except ValidationError as exc:
        raise FormatError(f"{where}: {validation_message(exc)}") from None
    models: dict[str, AnyCamera] = {}
    for name, cam in parsed.cameras.items():
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


def read_cameras(path: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, AnyCamera]]:
    """The ``cameras`` object of cameras.json (or of a calibration.json) and its models.

    Raises
    ------
    FormatError
        Missing, not JSON, another format, no cameras, or a camera that does not validate.
    """
    p = Path(path)
    raw = read_versioned_json(
        p, (CAMERAS_FORMAT, "microcal.calibration/1"), " (run 'microcal stereo-calibrate' first)"
    )
    if not raw.get("cameras"):
        raise FormatError(f"{p}: holds no cameras")
    section: dict[str, Any] = raw["cameras"]
    return section, models_from_dict({"format": CAMERAS_FORMAT, "cameras": section}, str(p))


def load_cameras(path: str | os.PathLike[str]) -> dict[str, AnyCamera]:
    """Read cameras.json (or a calibration.json that holds cameras)."""
    return read_cameras(path)[1]
