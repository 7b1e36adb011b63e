"""The run directory of ``microcal acquire``: its options, a new run or a resumed one.

A new run records in run.json every option that shapes it (rig, design, settle, frames,
store); ``--resume`` reads them back, so ``microcal acquire --out RUN --resume`` needs no
other option, and an option given again must agree with the recorded one.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

from numpy.typing import ArrayLike

from .._validation import FloatArray, did_you_mean
from ..errors import InputError, MicrocalError
from ..formats.cameras_file import CAMERAS_FORMAT
from ..formats.file_lock import lock_path
from ..formats.json_file import read_versioned_json
from ..formats.outputs import check_writable
from ..formats.records import MAX_FRAMES_PER_POSE, RunManifest
from ..formats.run_directory import HOLDS_A_RUN, MANIFEST, RunDirectory, RunWriter, holds_run
from ..formats.run_lock import run_lock
from ..formats.run_manifest import new_manifest
from ..journal_record import JournalRecord
from ..kinematics.designs import DESIGNS
from ..kinematics.models import held_from_limits
from ..procedures.acquisition import AcquisitionConfig, RunStoppedError
from ..procedures.acquisition import acquire as run_acquisition
from ..procedures.planning import (
    DESIGN_CHOICES,
    POLYNOMIAL_POSES,
    RunPlan,
    check_poses,
    plan_run,
)

__all__ = [
    "DEFAULTS",
    "AcquireRequest",
    "acquire_remaining",
    "check_out",
    "check_same_rig",
    "plan_for",
    "run_acquire",
]

#: The options of a new run that the command line leaves out.
DEFAULTS: dict[str, Any] = {
    "rig": "sim", "design": "random", "poses": 170, "seed": 0, "settle": "vision", "frames": 5,
    "store": "full", "manipulator": "m1",
}  # fmt: skip
_RECORDED = {"settle": "settle", "frames": "frames_per_pose", "store": "store",
             "manipulator": "manipulator"}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class AcquireRequest:
    """What ``microcal acquire`` was asked for; None is an option left out."""

    out: Path
    rig: str | None = None
    design: str | None = None
    poses: int | None = None
    seed: int | None = None
    resume: bool = False
    settle: str | None = None
    frames: int | None = None
    store: str | None = None
    dry_run: bool = False
    manipulator: str | None = None
    check_calibration: str | None = None
    check_every: str | None = None
    until_um: float | None = None
    max_poses: int | None = None
    cameras: str | None = None
    scope: Path | None = None
    objective: str | None = None
    volume_um: str | None = None
    approach_deg: float | None = None
    azimuth_deg: float | None = None

    def filled(self, manifest: RunManifest | None = None) -> AcquireRequest:
        """Every option set: a new run's defaults, or what a resumed run recorded.

        Raises
        ------
        InputError
            On resume, an option that differs from the one run.json records.
        """
        values: dict[str, Any] = {}
        for name, default in DEFAULTS.items():
            given = getattr(self, name)
            if manifest is None or name == "rig":
                values[name] = default if given is None else given
                continue
            recorded = _recorded(manifest, name)
            if name == "design" and given is not None and given not in DESIGN_CHOICES:
                given = "file"  # a CSV of commands: the run holds its own copy
            if given is not None and recorded is not None and given != recorded:
                raise InputError(
                    f"--{name} {getattr(self, name)}: this run was begun with --{name} "
                    f"{recorded} ({MANIFEST}); leave --{name} out to resume it"
                )
            values[name] = (
                given if given is not None else recorded if recorded is not None else default
            )
        return dataclasses.replace(self, **values)


def _recorded(manifest: RunManifest, name: str) -> Any:
    """The value run.json records for an option (None when it records none)."""
    design = manifest.design
    if name in ("design", "poses", "seed"):
        key = "kind" if name == "design" else name
        return getattr(design, key) if design is not None else None
    if name == "manipulator":
        return manifest.manipulator or "m1"
    return getattr(manifest, _RECORDED[name])


def check_out(out: Path, resume: bool, dry_run: bool) -> None:
    """Refuse, before any device is opened, a run directory that does not fit the request.

    A new run goes into a new or empty directory: never over a run, nor among other files
    (a user's own commands.csv or images would be replaced). The files of the step before
    it may be there: the cameras microcal calibrated (cameras.json, and the views it grabbed
    for them, cameras-views/), which the run never writes over.
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory for the run")
    if not dry_run:
        check_writable(out, f"--out {out}")
    if resume:
        if not (out / MANIFEST).exists():
            raise InputError(f"{out}: no run to resume (no {MANIFEST}); start it without --resume")
        return
    if not out.exists():
        return
    if holds_run(out):  # a dry run says so too: the run it checks for could not start there
        raise InputError(f"{out}: {HOLDS_A_RUN}")
    others = sorted(p.name for p in out.iterdir() if not _earlier_step(p))
    if others:
        shown = ", ".join(others[:3]) + (", ..." if len(others) > 3 else "")
        raise InputError(
            f"--out {out}: holds other files ({shown}); a new run needs a new or empty directory"
        )


#: What ``stereo-calibrate --out RUN/cameras.json`` leaves in a run directory before its run.
_CAMERAS = "cameras.json"
_CAMERA_VIEWS = "cameras-views"


def _earlier_step(path: Path) -> bool:
    """Whether ``path`` in a new run's directory is what calibrating the cameras left there:
    a microcal cameras file named cameras.json, its views' folder, or their locks."""
    if path.is_symlink():
        return False
    if path.name == _CAMERA_VIEWS:
        return path.is_dir()
    if path.name == lock_path(_CAMERAS).name:
        return path.is_file()
    if path.name != _CAMERAS or not path.is_file():
        return False
    try:
        read_versioned_json(path, (CAMERAS_FORMAT,))
    except MicrocalError:
        return False
    return True


def plan_for(
    design: str, poses: int, seed: int, limits_um: ArrayLike, axes: tuple[str, ...]
) -> RunPlan:
    """The plan of ``--design``: a named design over the limits, or a CSV file of commands."""
    if design in DESIGN_CHOICES:
        return plan_run(design, poses, seed, limits_um, axes=axes)
    from ..formats.commands_csv import read_joint_csv

    if not Path(design).is_file():
        raise InputError(
            f"--design {design}: not a design ({', '.join(DESIGN_CHOICES)}) and no such file"
        )
    commands = read_joint_csv(Path(design), what="--design")[1]
    return plan_run("file", poses, seed, limits_um, axes=axes, commands_um=commands)


def run_acquire(request: AcquireRequest) -> Iterator[str]:
    """``microcal acquire``: check the request, open the rig, acquire (or dry-run) the run.

    Yields the lines to print. Nothing is created before the options, the run directory and
    the devices are checked; the run directory is locked while the run goes on.

    Raises
    ------
    MicrocalError
        A bad option, a run directory that does not fit, a rig that does not open, or a run
        stopped (with the command that resumes it).
    """
    from ..formats.rig_file import load_rig, rig_from_record
    from ..procedures.dry_run import dry_run as check_rig
    from .check import PeriodicCheck, parse_every
    from .options import parse_settle
    from .rigs import open_rig

    out = request.out
    if request.resume and request.dry_run:
        raise InputError("--dry-run and --resume: choose one")
    if request.until_um is not None or request.max_poses is not None or request.cameras:
        raise InputError("--until-um, --max-poses and --cameras: for --design adaptive only")
    check_out(out, request.resume, request.dry_run)
    manifest = RunDirectory(out).manifest if request.resume else None
    req = request.filled(manifest)
    if (
        manifest is None
        and req.design not in DESIGN_CHOICES
        and not Path(str(req.design)).is_file()
    ):
        hint = did_you_mean(req.design, DESIGN_CHOICES, quote=False)
        raise InputError(f"--design {req.design}: not a design ({hint}designs: "
                         f"{', '.join(DESIGN_CHOICES)}) and no such CSV file")  # fmt: skip
    if manifest is None and req.design in DESIGNS:
        check_poses(str(req.design), cast(int, req.poses))
    elif request.poses is not None and manifest is None:
        raise InputError(f"--poses: design {req.design} has its own poses; leave --poses out")
    if not 1 <= cast(int, req.frames) <= MAX_FRAMES_PER_POSE:
        raise InputError(
            f"--frames: expected 1 to {MAX_FRAMES_PER_POSE} frames per camera and pose, "
            f"got {req.frames}"
        )
    if req.store not in ("full", "roi"):
        raise InputError(f"--store: expected 'full' or 'roi', got {req.store!r}")
    mode, fixed_s = parse_settle(str(req.settle))
    if req.check_every is not None and req.check_calibration is None:
        raise InputError("--check-every: give the calibration to check (--check-calibration)")
    if req.check_every is not None:
        parse_every(req.check_every)
    if manifest is not None and request.rig is None:
        spec = rig_from_record(_simulated_record(out, manifest), str(out / MANIFEST))
    else:
        spec = load_rig(str(req.rig))
    if manifest is not None:
        check_same_rig(out, manifest.rig, spec.to_dict())  # before any device is opened
    config = AcquisitionConfig(settle=mode, fixed_s=fixed_s, frames_per_pose=cast(int, req.frames),
                               store_roi=req.store == "roi")  # fmt: skip
    with open_rig(spec, str(req.manipulator)) as opened:
        m = opened.manipulator
        plan = None
        if manifest is None:
            plan = plan_for(
                str(req.design), cast(int, req.poses), cast(int, req.seed), m.limits_um, m.axes
            )
            if req.design in DESIGNS and plan.poses < POLYNOMIAL_POSES:
                yield (f"note: {plan.poses} poses identify the matrix model; the polynomial "
                       f"model needs about {POLYNOMIAL_POSES}")  # fmt: skip
        if plan is not None and req.dry_run:
            yield from check_rig(m, opened.cameras, opened.board, plan, opened.description)
            return
        periodic = None
        if req.check_calibration is not None:
            periodic = PeriodicCheck(opened, req.check_calibration, req.check_every or "20", out,
                                     say=print)  # fmt: skip
        with _run_directory(out, creating=plan is not None), run_lock(out, "acquire"):
            writer, pose_ids, d = _open_run(out, spec, opened, plan, req)
            hint = f"microcal acquire --out {out} --resume"
            yield from acquire_remaining(
                opened, writer, pose_ids, d, config, hint, req.resume, periodic
            )


def first_pose_disk_line(pose_bytes: int, poses: int) -> str:
    """The disk the first pose took, and the run's at that rate (said after the first pose:
    a region of interest's size is known only once the target is seen)."""
    return (f"the first pose took {pose_bytes / 1e6:.2g} MB on disk: about "
            f"{poses * pose_bytes / 1e6:.2g} MB for the {poses} poses")  # fmt: skip


def disk_use_line(cameras: Any, poses: int, config: AcquisitionConfig) -> str:
    """The disk a run's images will take, said before it starts: their size before the
    lossless compression (which saves what the images allow); a region of interest takes a
    fraction of it.

    ``cameras``: name -> camera (``sensor_size_px``, ``bit_depth``).
    """
    per_pose = (
        sum(
            c.sensor_size_px[0] * c.sensor_size_px[1] * (1 if c.bit_depth <= 8 else 2)
            for c in cameras.values()
        )
        * config.frames_per_pose
    )
    total_gb = poses * per_pose / 1e9
    sizes = ", ".join(f"{c.sensor_size_px[0]} x {c.sensor_size_px[1]} px" for c in cameras.values())
    what = (f"{poses} poses x {len(cameras)} camera(s) x {config.frames_per_pose} frame(s) "
            f"of {sizes}")  # fmt: skip
    if config.store_roi:
        return (f"images: at most {total_gb:.2g} GB ({what}); --store roi keeps only the region "
                f"around the target, measured after the first pose")  # fmt: skip
    line = f"images: up to {total_gb:.2g} GB on disk ({what}; less as they compress)"
    if total_gb > 0.2:
        line += "; --store roi keeps only the region around the target, a fraction of it"
    return line


def _simulated_record(out: Path, manifest: RunManifest) -> object:
    """The rig run.json records, for a resume without ``--rig``: the simulator only.

    A run directory is data that is copied and shared: a hardware rig it records could name
    any module to import and any address to connect to, so it is never opened from there.
    """
    record = manifest.rig
    if isinstance(record, dict) and record.get("driver") != "sim":
        raise InputError(
            f"{out / MANIFEST}: this run was made on a hardware rig, and a resume opens no "
            "device a run directory names; pass --rig with the rig file the run was started with"
        )
    return record


def check_same_rig(out: Path, recorded: object, rig: object) -> None:
    """Refuse a resume on a rig other than the one run.json records (records compared).

    Raises
    ------
    InputError
        Another rig: the message names the run, not the record's contents.
    """
    if recorded != rig:
        raise InputError(
            f"{out}: this run was made with another rig (its {MANIFEST} records other "
            "settings); resume it with that rig: --rig with the rig file the run was started with"
        )


@contextlib.contextmanager
def _run_directory(out: Path, creating: bool) -> Iterator[None]:
    """The run directory for the lock; a new one that the run never began in is removed."""
    made = creating and not out.exists()
    if made:
        out.mkdir(parents=True)
    try:
        yield
    except BaseException:
        if made and not holds_run(out):
            with contextlib.suppress(OSError):
                for leftover in (out / "images", out / ".microcal.lock"):
                    leftover.rmdir() if leftover.is_dir() else leftover.unlink(missing_ok=True)
                out.rmdir()
        raise


def _open_run(
    out: Path, rig: Any, opened: Any, plan: RunPlan | None, req: AcquireRequest
) -> tuple[RunWriter, list[int], FloatArray]:
    """The writer of the run, its pose numbers and commands: a new run from ``plan``, or the
    run in ``out`` resumed (it must come from the same rig and be unedited)."""
    device = opened.manipulator.identity
    if plan is None:
        recorded = RunDirectory(out).manifest
        before = recorded.device if recorded is not None else None
        if before and device and before != device:
            raise InputError(
                f"{out}: this run was begun on {before}, but the rig's manipulator is {device}; "
                "resume it on the same device, or start a new run"
            )
        writer = RunDirectory.resume(out, rig.to_dict())
        pose_ids, d = RunDirectory.open(out).commands()
        return writer, pose_ids, d
    manifest = new_manifest(
        rig=rig.to_dict(),
        target=opened.board.spec,
        cameras=list(opened.cameras),
        design=plan.design_record(),
        settle=str(req.settle),
        frames_per_pose=cast(int, req.frames),
        store=str(req.store),
        command="acquire",
        device=device,
        manipulator=opened.selected,
        held_joints_um=held_from_limits(opened.manipulator.limits_um),
    )
    writer = RunDirectory.create(out, manifest, plan.d_um)
    return writer, list(range(1, plan.poses + 1)), plan.d_um


def acquire_remaining(
    opened: Any,
    writer: RunWriter,
    pose_ids: list[int],
    d: FloatArray,
    config: AcquisitionConfig,
    resume_hint: str,
    resume: bool,
    periodic: Any = None,
) -> Iterator[str]:
    """Acquire the poses of a run not yet stored, stopping cleanly on Ctrl-C or SIGTERM.

    Yields the lines to show: the start, progress where the output is not a terminal (a bar
    where it is), what was stored and every pose that failed. ``periodic``: a
    :class:`~microcal.workflows.check.PeriodicCheck` run between poses (its lines are
    printed as it makes them).

    Raises
    ------
    RunStoppedError
        The run was stopped (a signal, a device that stopped answering): how many poses are
        stored and the command that resumes it.
    """
    import numpy as np
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from ..formats.check_file import history_path

    yield from writer.repairs
    said = len(writer.repairs)
    todo = writer.remaining(pose_ids)
    verb = "resuming" if resume else "starting"
    yield f"{verb} {writer.run_dir}: {len(todo)} of {len(pose_ids)} poses to do"
    yield disk_use_line(opened.cameras, len(todo), config)
    stop = {"requested": False}
    failed: list[tuple[int, str]] = []
    settles: list[float] = []
    tty = sys.stdout.isatty()
    count = TextColumn("{task.completed}/{task.total}")
    bar = Progress(TextColumn("acquiring"), BarColumn(), count, TimeRemainingColumn(),
                   disable=not tty)  # fmt: skip
    task = bar.add_task("acquire", total=len(todo))
    say: Callable[[str], None] = bar.console.print if tty else lambda line: print(line, flush=True)
    if periodic is not None:
        periodic.say = say
        periodic.stored_before = len(writer.done)
    size_before = writer.size_bytes()

    def progress(done: int, total: int, record: JournalRecord) -> None:
        settles.append(record.settle_s)
        if record.status != "ok":
            failed.append((record.pose, record.reason or ""))
        bar.update(task, completed=done)
        if done == 1 and total > 1 and record.status == "ok":  # the estimate above, measured
            say(first_pose_disk_line(writer.size_bytes() - size_before, total))
        if not tty and (done % 10 == 0 or done == total):
            print(f"acquired {done}/{total} poses", flush=True)  # while the run goes on

    previous = {s: signal.signal(s, lambda *_: stop.update(requested=True))
                for s in (signal.SIGINT, signal.SIGTERM)}  # fmt: skip
    try:
        with bar:
            run_acquisition(opened.manipulator, opened.cameras, opened.clock, d, todo,
                            opened.board, writer.store, config=config,
                            should_stop=lambda: stop["requested"], sensors=opened.sensors,
                            progress=progress, between=periodic)  # fmt: skip
    except RunStoppedError as exc:
        raise RunStoppedError(f"run stopped ({exc}); {len(writer.done)} of {len(pose_ids)} "
                              f"poses stored; resume with: {resume_hint}",
                              interrupted=stop["requested"]) from None  # fmt: skip
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    size_mb = writer.size_bytes() / 1e6
    settle = "vision" if config.settle == "vision" else f"fixed:{config.fixed_s:g}"
    if not settles:
        how = "no pose was left to acquire"
    else:
        how = f"mean settle {float(np.mean(settles)):.2f} s ({settle})"
        if len(settles) < len(writer.done):  # a resumed run: the poses before are journaled
            how += f" over the {len(settles)} poses acquired now"
    yield (f"stored {len(writer.done)} of {len(pose_ids)} poses in {writer.run_dir} "
           f"({size_mb:.1f} MB); {how}")  # fmt: skip
    for pose, reason in failed:
        yield f"pose {pose} failed: {reason}"
    yield from writer.repairs[said:]  # an image found where a pose's image went, kept aside
    if periodic is not None and periodic.results:
        verdicts = ", ".join(r.verdict for r in periodic.results)
        yield (f"{len(periodic.results)} checks of {periodic.path} during the run: {verdicts} "
               f"(history: {history_path(periodic.path)})")  # fmt: skip
