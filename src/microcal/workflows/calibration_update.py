"""Adding a manipulator's calibration to calibration.json (what ``microcal fit`` writes)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..formats.calibration_file import (
    Calibration,
    export_mat,
    load_calibration,
    write_calibration,
)
from ..formats.cameras_file import read_cameras
from ..formats.file_lock import locked_update
from ..formats.provenance import provenance
from ..formats.records import RunManifest
from ..geometry import AnyCamera
from ..kinematics.manipulator_calibration import ManipulatorCalibration

__all__ = [
    "add_manipulator",
    "camera_models",
    "manifest_beside",
    "measured_device",
    "measured_held_joints",
]


def manifest_beside(measurements: Path) -> RunManifest | None:
    """run.json of the run directory holding ``measurements``, if there is one."""
    from ..formats.run_directory import RunDirectory

    if not (measurements.parent / "run.json").is_file():
        return None
    return RunDirectory(measurements.parent).manifest


def measured_device(manifest: RunManifest | None) -> str:
    """The rig device whose run is ``manifest`` (run.json beside the measurements), else
    ``m1``."""
    return (manifest.manipulator if manifest is not None else None) or "m1"


def measured_held_joints(manifest: RunManifest | None) -> dict[str, float]:
    """The joints the measured device holds still (``manifest``, run.json beside the
    measurements: an X-Y positioner's ``dz``), by value; none without a run.json."""
    return dict(manifest.held_joints_um or {}) if manifest is not None else {}


def add_manipulator(
    out: Path,
    entry: ManipulatorCalibration,
    cameras: Path | None,
    inputs: dict[str, Any],
    model: str,
    manifest: RunManifest | None = None,
    mat: Path | None = None,
) -> Calibration:
    """Write ``out`` with ``entry`` added (or replaced); returns what was written.

    An existing file keeps its other manipulators and its cameras, unless ``cameras`` (a
    cameras.json) gives new ones. ``inputs`` are the files the calibration was made from;
    ``manifest`` the run they were measured in (its device is recorded with the entry);
    ``mat`` a .mat file to export the written calibration to as well.

    The device's tool-centre point (``tool_centre``, :mod:`microcal.workflows.tool_centre`)
    in an existing ``out`` is kept when the new entry has none: a new fit of the board does
    not move the tool on it.

    ``out`` is read and written under its lock (:func:`~microcal.formats.file_lock.locked_update`,
    the .mat export too): two fits into one file at once keep both entries.
    """
    if manifest is not None and manifest.device and "device" not in entry.extra:
        entry = dataclasses.replace(entry, extra={**entry.extra, "device": manifest.device})
    with locked_update(out):
        existing = load_calibration(out, link_ok=False) if out.exists() else None
        camera_data = existing.cameras if existing else {}
        if cameras is not None:
            camera_data = read_cameras(cameras)[0]
        manipulators = dict(existing.manipulators) if existing else {}
        before = manipulators.get(entry.name)
        kept = before.extra.get("tool_centre") if before is not None else None
        if kept is not None and "tool_centre" not in entry.extra:
            entry = dataclasses.replace(entry, extra={**entry.extra, "tool_centre": kept})
        manipulators[entry.name] = entry
        calibration = Calibration(
            manipulators,
            cameras=camera_data,
            provenance=provenance(inputs, command="fit", model=model),
        )
        write_calibration(out, calibration)
        if mat is not None:
            export_mat(mat, calibration)
    return calibration


def check_fit_outputs(out: Path, mat: Path | None, manipulator: str | None = "m1") -> None:
    """Refuse, before the fit, a calibration.json or .mat output that is not ours to replace,
    or an empty manipulator name."""
    from ..formats.calibration_file import CALIBRATION_FORMAT
    from ..formats.json_file import check_json_output
    from ..formats.outputs import check_output, foreign_mat

    if manipulator is not None and not manipulator.strip():
        raise InputError("--manipulator: expected a name such as m1, got an empty one")
    check_json_output(out, CALIBRATION_FORMAT, "calibration.json")
    if mat is not None:
        if mat.resolve() == out.resolve():
            raise InputError(f"--mat {mat}: is --out too; give the .mat file its own name")
        check_output(mat, kind="a .mat file of models", foreign=foreign_mat,
                     example="calibration.mat", option="--mat")  # fmt: skip


def camera_models(calibration: Calibration) -> dict[str, AnyCamera]:
    """The calibrated cameras a calibration holds (``fit --cameras`` put them there).

    Raises
    ------
    InputError
        A calibration without cameras, saying how to add them.
    """
    if not calibration.cameras:
        where = str(calibration.path) if calibration.path else "calibration"
        raise InputError(
            f"{where}: holds no cameras; run 'microcal fit ... --cameras cameras.json' (a "
            f"one-camera rig's calibration has none: this command needs two cameras or more)"
        )
    return calibration.camera_models()
