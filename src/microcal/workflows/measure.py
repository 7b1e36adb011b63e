"""``microcal measure`` on a run directory: verified inputs in, a measurements.csv that is
never worse than the one it replaces out.

The run's commands and images are measured only as run.json and the journal recorded them
(their SHA-256: :meth:`RunDirectory.commands`, :meth:`RunDirectory.frames`); the run is
locked while it is measured; a measurements.csv is written only when some pose was
measured, and it replaces an earlier one with more measured poses only with ``force``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import FormatError, InputError
from ..formats.run_directory import RunDirectory
from ..formats.run_lock import run_lock

__all__ = ["MeasuredRun", "measure_run"]

#: The board a run without run.json is measured with (the thesis's end-effector).
DEFAULT_TARGET = "chessboard:4x3:400"


@dataclass
class MeasuredRun:
    """What ``measure_run`` measured and wrote.

    Attributes
    ----------
    results : list of PoseMeasurement
        One per pose of commands.csv, in order.
    path : Path
        The measurements.csv written.
    notes : list of str
        Warnings to show (damaged journal lines).
    """

    results: list[Any]
    path: Path
    notes: list[str] = field(default_factory=list)


def _ok_poses(path: Path) -> int | None:
    """How many poses an existing measurements.csv measured (None when there is none).

    Raises
    ------
    InputError
        The file is not a measurements.csv microcal reads (it is not ours to replace).
    """
    from ..formats.measurements import read_measurements

    if path.is_dir():
        raise InputError(f"{path}: is a directory; move it away to measure this run")
    if not path.exists():
        return None
    try:
        return int(read_measurements(path, link_ok=False).pose.size)
    except FormatError as exc:
        raise InputError(
            f"{path}: not a measurements.csv microcal can read ({exc}); microcal replaces only "
            f"its own files: move it away"
        ) from None


def measure_run(
    run_dir: str | os.PathLike[str],
    cameras: str | os.PathLike[str] | None,
    target: str | None = None,
    *,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    workers: int | None = None,
) -> MeasuredRun:
    """Measure every pose of a run and write its ``measurements.csv``.

    Parameters
    ----------
    run_dir : path
        The run directory.
    cameras : path
        cameras.json (or a calibration.json with cameras); None only for a one-camera run,
        which is refused naming ``fit`` (it was measured as it was acquired).
    target : str, optional
        The end-effector's board (default: run.json's).
    force : bool
        Replace a measurements.csv that measured more poses than this measurement.
    progress : callable (done, total), optional
        A camera's frames of a pose at a time.
    workers : int, optional
        Cameras measured at once, each in its own process (default: the machine's cores);
        the results are the same for any number.

    Raises
    ------
    MicrocalError
        Inputs that do not load, commands edited since the run began, another process
        measuring or acquiring the run, no pose measured (nothing written), or fewer poses
        measured than the measurements.csv it would replace (kept; ``force`` replaces it).
    """
    from ..formats.cameras_file import load_cameras
    from ..formats.one_camera_run import is_one_camera_run
    from ..vision.effector_target import parse_effector_target
    from ..vision.measurement import measure_poses

    if is_one_camera_run(run_dir):
        raise InputError(
            f"{run_dir}: a one-camera run, measured as it was acquired (its measurements.csv "
            f"holds each tip in the microscope's frame with its covariance); fit it: "
            f"microcal fit {run_dir}"
        )
    if cameras is None:
        raise InputError(
            "--cameras: measuring a run needs its cameras' calibration (cameras.json from "
            "microcal stereo-calibrate, or a calibration.json with cameras)"
        )
    run = RunDirectory.open(run_dir, require_commands=False)
    models = load_cameras(cameras)
    poses, d = run.commands()
    if run.manifest is not None and not (run.path / "journal.jsonl").is_file():
        raise FormatError(
            f"{run.path / 'journal.jsonl'}: missing; without it the run's images cannot be "
            f"verified (restore it, or acquire the run again)"
        )
    try:
        board = parse_effector_target(target or run.target_spec or DEFAULT_TARGET)
    except InputError as exc:
        where = "--target" if target else f"{run.path / 'run.json'}: target"
        raise InputError(f"{where}: {exc}") from None
    previous = _ok_poses(run.measurements_path)
    if not os.access(run.path, os.W_OK):
        raise InputError(f"{run.path}: cannot write measurements.csv there (no permission)")
    notes = [f"warning: {n}; its poses are not measured (acquire --resume acquires them again)"
             for n in [run.damage_note()] if n]  # fmt: skip
    with run_lock(run.path, "measure"):

        def frames(pose: int, camera: str) -> list[Any]:
            model = models.get(camera)  # the camera's size bounds its images
            return run.frames(pose, camera, model.image_size_px if model is not None else None)

        results = measure_poses(
            poses,
            d,
            frames,
            models,
            board,
            progress=progress,
            workers=workers,
        )
        ok = sum(r.status == "ok" for r in results)
        failed = [r for r in results if r.status != "ok"]
        kept = f"; kept {run.measurements_path}" if previous is not None else ""
        if ok == 0:
            first = f" (pose {failed[0].pose}: {failed[0].reason})" if failed else ""
            raise InputError(
                f"no pose measured, all {len(results)} failed{first}; nothing written{kept}: "
                f"check --cameras and --target ({board.spec})"
            )
        if previous is not None and ok < previous and 2 * ok < len(results) and not force:
            raise InputError(
                f"only {ok} of {len(results)} poses measured, fewer than the {previous} of the "
                f"measurements.csv it would replace{kept}: check --cameras and --target, or "
                f"give --force to replace it"
            )
        path = run.write_measurements(poses, d, results)
    return MeasuredRun(results, path, notes)
