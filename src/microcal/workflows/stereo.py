"""``microcal stereo-calibrate``: cameras calibrated from image files, or on a rig.

From image files (:func:`stereo_calibrate_images`): the target detected in each view of each
camera, the cameras calibrated (known displacements or unknown poses), cameras.json written
with each image's hash.

On a rig (:func:`stereo_calibrate_rig`):

The frames of every view are kept as multi-page TIFFs (``top_01.tiff`` ...) with the steps
(``steps.csv``) in a views directory, so that ``microcal stereo-calibrate --images ...
--known-displacements steps.csv`` repeats the calibration from them exactly; cameras.json
records their hashes as its provenance, like a calibration from image files.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..devices.rig_spec import HardwareRigSpec
from ..errors import InputError
from ..formats.cameras_file import CAMERAS_FORMAT, save_stereo_calibration
from ..formats.commands_csv import read_joint_csv, write_joint_csv
from ..formats.images import write_tiff
from ..formats.json_file import check_json_output
from ..formats.rig_file import load_rig
from ..procedures.rig_stereo import (
    RigViewsConfig,
    calibrate_on_rig,
    default_steps_um,
    view_name,
)
from ..vision.stereo_calibration import StereoCalibration
from ..vision.targets import parse_target
from .options import rig_with_seed
from .rigs import open_rig

__all__ = [
    "STEPS_FILE",
    "RigViewsConfig",
    "stereo_calibrate_images",
    "stereo_calibrate_rig",
]

#: The steps' file in the views directory.
STEPS_FILE = "steps.csv"
_NO_STAGE = (
    "--rig: the rig has no target stage; add [target_stage] and calibration_target to the "
    "rig file (docs/hardware.md), or calibrate from image files with --images"
)
_OURS = re.compile(r"^[A-Za-z0-9_.-]+_\d{2,}\.tiff$")


def _check_views_dir(path: Path) -> None:
    """The views directory may be new, or hold only files of an earlier run (replaced)."""
    if path.exists() and not path.is_dir():
        raise InputError(f"--views: {path} is a file; give a directory for the views' frames")
    if path.is_dir():
        foreign = [
            p.name for p in path.iterdir() if p.name != STEPS_FILE and not _OURS.match(p.name)
        ]
        if foreign:
            raise InputError(
                f"--views: {path} holds files microcal did not write ({foreign[0]}, ...); "
                f"give a new or empty directory"
            )


def stereo_calibrate_rig(
    rig: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    views: str | os.PathLike[str] | None = None,
    steps: str | os.PathLike[str] | None = None,
    target: str | None = None,
    seed: int | None = None,
    config: RigViewsConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[StereoCalibration, Path, Path]:
    """Calibrate the rig's cameras by moving its target stage (method (a)); write the files.

    Parameters
    ----------
    rig : path or "sim"
        The rig file (or the simulated platform).
    out : path
        cameras.json to write (new, or one microcal wrote).
    views : path, optional
        Directory for the frames and the steps (default: ``<out stem>-views`` beside ``out``).
    steps : path, optional
        CSV of steps (``dx_um,dy_um,dz_um`` per view); default: 0-4 mm along z in 1 mm steps.
    target : str, optional
        The target's spec (default: the rig's ``calibration_target``).
    seed : int, optional
        The simulated rig's seed.
    config : RigViewsConfig, optional
    progress : callable (done, total), optional

    Returns
    -------
    calibration, cameras.json path, views directory
    """
    out_path = check_json_output(out, CAMERAS_FORMAT, "cameras.json")
    views_dir = Path(views) if views is not None else out_path.with_name(f"{out_path.stem}-views")
    _check_views_dir(views_dir)
    steps_um = default_steps_um()
    if steps is not None:
        steps_um = read_joint_csv(steps, what="--known-displacements")[1]
    spec = rig_with_seed(load_rig(str(rig)), seed)
    if isinstance(spec, HardwareRigSpec) and spec.target_stage is None:
        raise InputError(_NO_STAGE)
    files: dict[str, list[Path]] = {}

    def store(view: int, camera: str, frames: list) -> None:  # type: ignore[type-arg]
        views_dir.mkdir(parents=True, exist_ok=True)
        files.setdefault(camera, []).append(write_tiff(views_dir / view_name(camera, view), frames))

    with open_rig(spec) as opened:
        if opened.target_stage is None or opened.calibration_target is None:
            raise InputError(_NO_STAGE)
        tgt = parse_target(target) if target is not None else opened.calibration_target
        cal = calibrate_on_rig(
            opened.target_stage,
            opened.cameras,
            opened.clock,
            tgt,
            steps_um,
            config=config,
            store=store,
            progress=progress,
        )
    steps_path = write_joint_csv(views_dir / STEPS_FILE, steps_um)
    save_stereo_calibration(out_path, cal, files, steps_path, tgt.spec)
    return cal, out_path, views_dir


def stereo_calibrate_images(
    target: str,
    images: list[str],
    out: Path,
    *,
    known_displacements: Path | None = None,
    reference_view: int = 0,
    lens_model: str = "auto",
    camera_model: str = "auto",
) -> StereoCalibration:
    """Calibrate cameras from image files and write cameras.json.

    Parameters
    ----------
    target : str
        The target spec (``chessboard:9x6:250``, ``dotgrid:...``).
    images : list of str
        ``CAMERA=GLOB`` per camera, each matching the same number of views; one camera alone
        calibrates from unknown poses (without ``known_displacements``).
    known_displacements : Path, optional
        The target's displacement of each view (CSV): the thesis's method; unknown poses
        without it.

    Raises
    ------
    InputError, FormatError, DetectionError
        One line naming the option, the file or the view.
    """
    from ..formats.images import read_frames
    from ..procedures.stereo import calibrate_views
    from .options import check_camera_model, parse_images

    tgt = parse_target(target)
    check_json_output(out, CAMERAS_FORMAT, "cameras.json")
    files = parse_images(images, at_least=1 if known_displacements is None else 2)
    n_views = len(next(iter(files.values())))
    disp = None
    if known_displacements is not None:
        disp = read_joint_csv(known_displacements, what="--known-displacements", rows=n_views)[1]

    def frames(cam: str, i: int) -> list[Any]:
        return read_frames(files[cam][i], link_ok=True)  # files the user's patterns name

    cal = calibrate_views({cam: [f.name for f in fs] for cam, fs in files.items()},
                          frames, tgt, displacements_um=disp,
                          reference_view=reference_view, lens_model=lens_model,
                          camera_model=check_camera_model(camera_model))  # fmt: skip
    save_stereo_calibration(out, cal, files, known_displacements, tgt.spec)
    return cal
