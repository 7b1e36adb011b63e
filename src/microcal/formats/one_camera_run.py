"""The run directory of a one-camera acquisition (``microcal acquire --scope ...``).

A one-camera rig measures each tip while it acquires (a focus sweep at the pose): the run
keeps no images, and its measurements are written as it goes.

- ``run.json``: the run's manifest (``microcal.run/1``: rig, target, camera, device), as any
  run's;
- ``one_camera.json`` (``microcal.one-camera/1``): what the poses follow from: the scope set
  used, the working volume, poses, seed, settle, the manipulator's angles, the joints'
  origin and the start's focus; written once, before anything moves;
- ``poses.jsonl``: one line per pose, on disk before the next pose begins: its journal
  record and its tip in {M} with its covariance
  (:class:`~microcal.formats.pose_journal.PoseJournal`);
- ``measurements.csv``: every pose so far: joints (counted from the origin), the tip in {M},
  its standard deviations and covariance, the approach directions; rewritten after each pose.

A resume reads ``one_camera.json`` and the journal back and goes on from the last pose.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from ..errors import FormatError
from ..json_value import JsonValue
from .atomic import write_text_atomic
from .json_file import parse_schema, read_versioned_json
from .records import RUN_FORMAT, RunManifest
from .run_directory import MANIFEST

__all__ = [
    "ONE_CAMERA_FILE",
    "ONE_CAMERA_FORMAT",
    "POSES_FILE",
    "is_one_camera_run",
    "read_one_camera_setup",
    "write_one_camera_run",
    "write_one_camera_setup",
]

ONE_CAMERA_FILE = "one_camera.json"
ONE_CAMERA_FORMAT = "microcal.one-camera/1"
POSES_FILE = "poses.jsonl"


def is_one_camera_run(run_dir: str | os.PathLike[str]) -> bool:
    """Whether ``run_dir`` holds a one-camera run (its ``one_camera.json``)."""
    return (Path(run_dir) / ONE_CAMERA_FILE).is_file()


def write_one_camera_run(
    run_dir: str | os.PathLike[str], manifest: dict[str, Any], setup: dict[str, JsonValue]
) -> None:
    """A new run's ``run.json`` (``manifest``: ``formats.run_manifest.new_manifest``'s, checked
    first) and ``one_camera.json``, each written atomically."""
    path = Path(run_dir)
    full = {"format": RUN_FORMAT, **manifest}
    parse_schema(RunManifest, full, f"{path / MANIFEST} (manifest)")
    write_text_atomic(path / MANIFEST, json.dumps(full, indent=1) + "\n")
    write_one_camera_setup(path, setup)


def write_one_camera_setup(run_dir: str | os.PathLike[str], setup: dict[str, JsonValue]) -> Path:
    """Write ``one_camera.json`` (``format`` first) atomically."""
    text = json.dumps({"format": ONE_CAMERA_FORMAT, **setup}, indent=2, allow_nan=False)
    return write_text_atomic(Path(run_dir) / ONE_CAMERA_FILE, text + "\n")


def read_one_camera_setup(run_dir: str | os.PathLike[str]) -> dict[str, object]:
    """``one_camera.json`` as parsed.

    Raises
    ------
    FormatError
        Missing, not JSON, another format, or without the keys a resume needs.
    """
    path = Path(run_dir) / ONE_CAMERA_FILE
    raw = read_versioned_json(path, (ONE_CAMERA_FORMAT,), "; not a one-camera run")
    needed = ("scope", "volume_half_um", "volume_centre_um", "poses", "seed", "settle_s",
              "approach_deg", "azimuth_deg", "joint_origin_um", "start_focus_um")  # fmt: skip
    missing = [k for k in needed if k not in raw]
    if missing:
        raise FormatError(f"{path}: missing {', '.join(missing)}; start a new run")
    return raw
