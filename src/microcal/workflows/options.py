"""Text given on the command line, turned into checked values (one place for each kind)."""

from __future__ import annotations

import dataclasses
import glob
import math
from pathlib import Path
from typing import Literal

import numpy as np

from .._validation import FloatArray, did_you_mean, name_problem
from ..devices.rig_spec import RigSpec, SimRigSpec
from ..errors import InputError

__all__ = [
    "check_camera_model",
    "parse_images",
    "parse_limits",
    "parse_number",
    "parse_position",
    "parse_settle",
    "rig_with_seed",
]


def parse_limits(text: str) -> FloatArray:
    """``LOW:HIGH,LOW:HIGH,LOW:HIGH`` (µm) -> (3, 2) soft limits."""
    try:
        pairs = [tuple(float(v) for v in part.split(":")) for part in text.split(",")]
        arr = np.array(pairs, dtype=np.float64)
    except ValueError:
        arr = np.zeros(0)
    if arr.shape != (3, 2) or not np.all(np.isfinite(arr)) or np.any(arr[:, 0] >= arr[:, 1]):
        raise InputError(
            f"--limits: expected LOW:HIGH for each joint, as 0:8000,0:8000,0:4800, got {text!r}"
        )
    return arr


def parse_position(values: list[float]) -> FloatArray:
    """Three finite numbers X Y Z (µm) -> (3,)."""
    if len(values) != 3:
        raise InputError(f"position: expected 3 numbers X Y Z in µm, got {len(values)}")
    target = np.array(values, dtype=np.float64)
    if not np.all(np.isfinite(target)):
        raise InputError(f"position: expected finite numbers, got {values}")
    return target


def parse_number(value: float, option: str) -> float:
    """A finite number given to ``option``."""
    if not math.isfinite(value):
        raise InputError(f"{option}: expected a finite number, got {value}")
    return float(value)


def parse_settle(text: str) -> tuple[Literal["vision", "fixed"], float]:
    """``vision`` or ``fixed:SECONDS`` -> (mode, seconds); seconds finite and >= 0."""
    if text == "vision":
        return "vision", 0.0
    kind, _, value = text.partition(":")
    try:
        seconds = float(value)
    except ValueError:
        seconds = -1.0
    if kind != "fixed" or not math.isfinite(seconds) or seconds < 0:
        raise InputError(
            f"--settle: expected 'vision' or 'fixed:SECONDS' such as fixed:30, got {text!r}"
        )
    return "fixed", seconds


def parse_images(specs: list[str], *, at_least: int = 2) -> dict[str, list[Path]]:
    """``CAMERA=GLOB`` options -> files per camera, sorted, one per view in every camera.

    Parameters
    ----------
    at_least : int
        How many cameras are needed at least.
    """
    out: dict[str, list[Path]] = {}
    for spec in specs:
        name, sep, pattern = spec.partition("=")
        if not sep or not name or not pattern:
            raise InputError(
                f"--images: expected CAMERA=GLOB such as top='cal/top_*.tiff', got {spec!r}"
            )
        problem = name_problem(name)
        if problem is not None:  # the camera's name in cameras.json and in file names
            raise InputError(f"--images: camera {problem}")
        if name in out:
            raise InputError(f"--images: camera {name!r} is given twice")
        files = sorted(Path(p) for p in glob.glob(pattern))
        if not files:
            raise InputError(f"--images {name}: no file matches {pattern!r}")
        out[name] = files
    if len(out) < at_least:
        raise InputError(
            f"--images: expected {at_least} cameras or more, got {sorted(out)}; give one "
            "--images CAMERA=GLOB per camera"
        )
    counts = {n: len(f) for n, f in out.items()}
    if len(set(counts.values())) != 1:
        raise InputError(f"--images: every camera needs one image per view, got {counts}")
    return out


def rig_with_seed(spec: RigSpec, seed: int | None) -> RigSpec:
    """The rig with ``--seed`` applied: the simulator's seed; refused for a hardware rig."""
    if seed is None:
        return spec
    if not isinstance(spec, SimRigSpec):
        raise InputError("--seed: only the simulated rig has a seed; leave it out for hardware")
    return dataclasses.replace(spec, seed=seed)


def check_camera_model(value: str, option: str = "--camera-model") -> str:
    """A camera model's name for method (a): pinhole, affine or auto.

    Raises
    ------
    InputError
        ``--camera-model: expected pinhole, affine or auto, got 'telecentric'``.
    """
    from ..vision.known_displacements import CAMERA_MODEL_CHOICES

    if value not in CAMERA_MODEL_CHOICES:
        hint = did_you_mean(value, CAMERA_MODEL_CHOICES, quote=False).strip()
        raise InputError(
            f"{option}: expected {', '.join(CAMERA_MODEL_CHOICES[:-1])} or "
            f"{CAMERA_MODEL_CHOICES[-1]}, got {value!r}" + (f" ({hint})" if hint else "")
        )
    return value
