"""``microcal acquire --design adaptive --until-um T``: acquisition, measurement and fit
interleaved, each next batch of poses chosen from what was measured.

The run directory ``RUN`` holds ``adaptive.json`` (the options, written once, before
anything moves) and one ordinary run directory per batch, ``RUN/batch-001`` (the
space-filling start), ``RUN/batch-002`` ...: each acquired as ``microcal acquire`` acquires
(journal, images, crash-safe) and measured into its own measurements.csv with the cameras
given. The next batch is a deterministic function of every batch's measurements
(:mod:`~microcal.procedures.adaptive`), so ``--resume`` after a crash resumes the batch
that was being acquired, measures what was not measured, and then chooses the very poses
the run would have chosen without the crash. A batch directory without its run.json (a
crash while it was being created) is made again.
"""

from __future__ import annotations

import contextlib
import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import FloatArray
from ..errors import FormatError, InputError, MicrocalError
from ..formats.atomic import write_text_atomic
from ..formats.run_directory import MANIFEST, RunDirectory
from ..formats.run_lock import run_lock
from ..formats.run_manifest import new_manifest
from ..kinematics.adaptive_design import ADAPTIVE, AdaptiveSettings
from ..kinematics.models import held_from_limits
from ..procedures.acquisition import AcquisitionConfig
from ..procedures.adaptive import Measured
from .adaptive_batches import ADAPTIVE_FILE, ADAPTIVE_FORMAT, APPROACH_UM, BatchedDesign

__all__ = [
    "ADAPTIVE_FILE",
    "ADAPTIVE_FORMAT",
    "APPROACH_UM",
    "BatchedDesign",
    "acquire_any",
    "run_adaptive_acquire",
]


def _batch_dir(out: Path, index: int) -> Path:
    return out / f"batch-{index + 1:03d}"


def _options(request: Any, out: Path) -> dict[str, Any]:
    """adaptive.json: a new run's options, or a resumed run's (options given again must
    agree)."""
    path = out / ADAPTIVE_FILE
    if request.resume:
        try:
            options: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise FormatError(f"{path}: cannot be read ({exc})") from None
        if options.get("format") != ADAPTIVE_FORMAT:
            raise FormatError(f"{path}: expected format {ADAPTIVE_FORMAT!r}")
        for key in ("until_um", "max_poses"):
            given = getattr(request, key)
            if given is not None and given != options[key]:
                flag = "--" + key.replace("_", "-")
                raise InputError(f"{flag} {given}: this run was begun with {options[key]} "
                                 f"({ADAPTIVE_FILE}); leave it out to resume")  # fmt: skip
        return options
    if request.until_um is None:
        raise InputError("--design adaptive: give the tolerance with --until-um (µm)")
    cameras = request.cameras or (out / "cameras.json")
    if not Path(cameras).is_file():
        raise InputError(
            "--design adaptive measures as it goes: give the cameras with --cameras, or "
            f"calibrate them into {out / 'cameras.json'} first (microcal stereo-calibrate)"
        )
    if out.exists() and any(p.name not in ("cameras.json", "cameras-views") for p in
                            out.iterdir()):  # fmt: skip
        raise InputError(f"--out {out}: holds other files; a new run needs a new directory")
    AdaptiveSettings(until_um=float(request.until_um), max_poses=int(request.max_poses or 400))
    return {
        "format": ADAPTIVE_FORMAT,
        "until_um": float(request.until_um),
        "max_poses": int(request.max_poses or 400),
        "seed": int(request.seed or 0),
        "cameras": str(Path(cameras).resolve()),
        "rig": str(request.rig or "sim"),
        "settle": str(request.settle or "vision"),
        "frames": int(request.frames or 20),
        "store": str(request.store or "full"),
        "manipulator": str(request.manipulator or "m1"),
    }


def _measured(batch: Path, cameras: str) -> Measured:
    """A batch's poses as measured (its measurements.csv, made when missing or stale)."""
    from ..formats.measurements import read_measurements
    from .measure import measure_run

    run = RunDirectory.open(batch)
    poses, d = run.commands()
    path = run.measurements_path
    journal = run.journal()
    if not path.is_file() or path.stat().st_mtime < (batch / "journal.jsonl").stat().st_mtime:
        with contextlib.suppress(InputError):  # none measured: all of them count as failed
            measure_run(batch, cameras, workers=1)
    p = np.full((len(poses), 3), np.nan)
    signs = np.full((len(poses), 3), np.nan)
    temps = np.zeros(len(poses))
    reported = np.full((len(poses), 3), np.nan)
    if path.is_file():
        m = read_measurements(path, link_ok=False)
        row = {int(k): i for i, k in enumerate(m.pose)}
        for k, pose in enumerate(poses):
            if pose in row:
                p[k] = m.p_um[row[pose]]
    for k, pose in enumerate(poses):
        line = journal.get(pose)
        if line is None:
            continue
        got = [line.get(f"approach_{a}") for a in "xyz"]
        signs[k] = [float(v) if isinstance(v, int | float) else np.nan for v in got]
        if line.temperature_c is not None:
            temps[k] = float(line.temperature_c)
        rep = line.get("reported_um")
        if isinstance(rep, list) and len(rep) == 3:
            reported[k] = [float(v) for v in rep]
    return Measured(np.asarray(d, dtype=np.float64), p, signs, temps, reported)


def acquire_any(request: Any) -> Iterator[str]:
    """``microcal acquire``: the one-camera run (``--scope``, or ``--resume`` of one:
    :mod:`~microcal.workflows.one_camera_acquire`), the adaptive run (``--design adaptive``,
    or ``--resume`` of a run directory holding adaptive.json), else
    :func:`~microcal.workflows.acquire.run_acquire`."""
    from .acquire import run_acquire
    from .one_camera_acquire import (
        refuse_one_camera_options,
        run_one_camera_acquire,
        wants_one_camera,
    )

    out: Path = request.out
    if wants_one_camera(request):
        yield from run_one_camera_acquire(request)
        return
    refuse_one_camera_options(request)
    adaptive = request.design == ADAPTIVE or (request.resume and (out / ADAPTIVE_FILE).is_file())
    if not adaptive:
        yield from run_acquire(request)
        return
    if request.dry_run or request.poses is not None or request.check_calibration:
        raise InputError("--design adaptive: chooses its own poses; leave out --poses, "
                         "--dry-run and --check-calibration")  # fmt: skip
    yield from run_adaptive_acquire(request)


def run_adaptive_acquire(request: Any) -> Iterator[str]:
    """The adaptive run (module docstring); yields the lines to print.

    Raises
    ------
    MicrocalError
        A bad option, a run directory that does not fit, a rig that does not open, or a run
        stopped (with the command that resumes it).
    """
    from ..formats.rig_file import load_rig
    from .acquire import check_out
    from .rigs import open_rig

    out: Path = request.out
    check_out(out, False, False) if not request.resume else None
    if request.resume and not (out / ADAPTIVE_FILE).is_file():
        raise InputError(f"{out}: no adaptive run to resume (no {ADAPTIVE_FILE})")
    options = _options(request, out)
    spec = load_rig(str(request.rig or options["rig"]))
    hint = f"microcal acquire --out {out} --resume"
    with open_rig(spec, options["manipulator"]) as opened:
        design = BatchedDesign(options, opened.manipulator.limits_um)
        out.mkdir(parents=True, exist_ok=True)
        if "workspace_um" not in options:  # the workspace the design covers: the limits
            options["workspace_um"] = np.asarray(opened.manipulator.limits_um).tolist()
            write_text_atomic(out / ADAPTIVE_FILE, json.dumps(options, indent=1) + "\n")
        with run_lock(out, "acquire"):
            measured = Measured.empty()
            plan, index, directions = design.start_um(), 0, None
            while True:
                batch = _batch_dir(out, index)
                config = design.batch_config(index, directions)
                yield from _acquire_batch(batch, index, plan, config, design, opened, spec, hint)
                measured = measured + _measured(batch, options["cameras"])
                step = design.step(measured)
                yield (f"batch {index + 1}: {step.used} of {step.poses} poses measured; "
                       f"{step.reason}")  # fmt: skip
                if step.stop:
                    break
                plan, index, directions = step.next_um, index + 1, step.next_directions
            yield from _finish(out, options)
    yield f"adaptive run in {out}: {len(measured)} poses in {index + 1} batches ({step.reason})"


def _finish(out: Path, options: dict[str, Any]) -> Iterator[str]:
    """Every pose in ``RUN/measurements.csv`` and the design's calibration of them in
    ``RUN/calibration.json`` (:mod:`~microcal.workflows.adaptive_fit`)."""
    from .adaptive_fit import fit_adaptive_run, merge_measurements, predicted_line

    merged = merge_measurements(out)
    target = out / "calibration.json"
    _, entry, _, poses, _ = fit_adaptive_run(out, target, Path(options["cameras"]))
    yield (f"wrote {merged} ({len(poses)} poses) and {target}: {predicted_line(entry)}; "
           f"microcal fit {out} --out OTHER.json fits it again")  # fmt: skip


def _acquire_batch(
    batch: Path, index: int, plan: FloatArray, config: AcquisitionConfig, design: BatchedDesign,
    opened: Any, spec: Any, hint: str,
) -> Iterator[str]:  # fmt: skip
    """Acquire one batch as ``config`` says: a new run directory of ``plan``, or the one
    there resumed."""
    from .acquire import acquire_remaining

    if batch.exists() and not (batch / MANIFEST).is_file():
        shutil.rmtree(batch)  # a crash while it was being created: made again
    resume = batch.exists()
    m, o = opened.manipulator, design.options
    if resume:
        writer = RunDirectory.resume(batch, spec.to_dict())
        pose_ids, d = RunDirectory.open(batch).commands()
    else:
        manifest = new_manifest(
            rig=spec.to_dict(), target=opened.board.spec, cameras=list(opened.cameras),
            design={"kind": ADAPTIVE, "poses": len(plan), "seed": config.approach_seed,
                    "until_um": o["until_um"], "batch": index + 1},
            settle=o["settle"], frames_per_pose=o["frames"], store=o["store"],
            command="acquire", device=m.identity, manipulator=opened.selected,
            held_joints_um=held_from_limits(m.limits_um),
        )  # fmt: skip
        writer = RunDirectory.create(batch, manifest, plan)
        pose_ids, d = list(range(1, len(plan) + 1)), plan
    if not writer.remaining(pose_ids):
        return
    with run_lock(batch, "acquire"):
        try:
            yield from acquire_remaining(opened, writer, pose_ids, d, config, hint, resume)
        except MicrocalError as exc:
            own = f"microcal acquire --out {batch} --resume"
            raise type(exc)(str(exc).replace(own, hint)) from None
