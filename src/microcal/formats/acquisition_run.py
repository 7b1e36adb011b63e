"""The run directory of ``microcal acquire``: its plan, a new run or a resumed one."""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..errors import InputError
from ..procedures.acquisition import AcquisitionConfig, RunStoppedError
from ..procedures.acquisition import acquire as run_acquisition
from ..procedures.planning import DESIGN_CHOICES, RunPlan, plan_run
from .run_directory import HOLDS_A_RUN, RunDirectory, RunWriter, holds_run
from .run_manifest import new_manifest

__all__ = ["acquire_remaining", "check_out", "open_run", "plan_for"]


def check_out(out: Path, resume: bool, dry_run: bool) -> None:
    """Refuse, before any device is opened, a run directory that does not fit the request."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory for the run")
    if not resume and not dry_run and holds_run(out):
        raise InputError(f"{out}: {HOLDS_A_RUN}")
    if resume and not (out / "run.json").exists():
        raise InputError(f"{out}: no run to resume (no run.json); start it without --resume")


def plan_for(
    design: str, poses: int, seed: int, limits_um: ArrayLike, axes: tuple[str, ...]
) -> RunPlan:
    """The plan of ``--design``: a named design over the limits, or a CSV file of commands."""
    if design in DESIGN_CHOICES:
        return plan_run(design, poses, seed, limits_um, axes=axes)
    from .commands_csv import read_joint_csv

    if not Path(design).exists():
        raise InputError(
            f"--design {design}: not a design ({', '.join(DESIGN_CHOICES)}) and no such file"
        )
    commands = read_joint_csv(Path(design), what="--design")[1]
    return plan_run("file", poses, seed, limits_um, axes=axes, commands_um=commands)


def open_run(
    out: Path,
    rig: Any,
    opened: Any,
    plan: RunPlan | None,
    settle: str,
    frames: int,
    store: str,
    resume: bool,
) -> tuple[RunWriter, list[int], FloatArray]:
    """The writer of the run, its pose numbers and commands: a new run from ``plan``, or the
    run in ``out`` resumed (it must come from the same rig and be unedited)."""
    if resume or plan is None:
        writer = RunDirectory.resume(out, rig.to_dict())
        pose_ids, d = RunDirectory.open(out).commands()
        return writer, pose_ids, d
    manifest = new_manifest(
        rig=rig.to_dict(),
        target=opened.board.spec,
        cameras=list(opened.cameras),
        design=plan.design_record(),
        settle=settle,
        frames_per_pose=frames,
        store=store,
        command="acquire",
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
) -> Iterator[str]:
    """Acquire the poses of a run not yet stored, stopping cleanly on Ctrl-C or SIGTERM.

    Yields the lines to show: the start, progress where the output is not a terminal (a bar
    where it is), what was stored and every pose that failed.

    Raises
    ------
    RunStoppedError
        The run was stopped (a signal, a device that stopped answering): how many poses are
        stored and the command that resumes it.
    """
    import numpy as np
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    todo = writer.remaining(pose_ids)
    verb = "resuming" if resume else "starting"
    yield f"{verb} {writer.run_dir}: {len(todo)} of {len(pose_ids)} poses to do"
    stop = {"requested": False}
    failed: list[tuple[int, str]] = []
    settles: list[float] = []
    tty = sys.stdout.isatty()
    count = TextColumn("{task.completed}/{task.total}")
    bar = Progress(TextColumn("acquiring"), BarColumn(), count, TimeRemainingColumn(),
                   disable=not tty)  # fmt: skip
    task = bar.add_task("acquire", total=len(todo))

    def progress(done: int, total: int, record: dict[str, Any]) -> None:
        settles.append(float(record["settle_s"]))
        if record["status"] != "ok":
            failed.append((int(record["pose"]), str(record.get("reason", ""))))
        bar.update(task, completed=done)
        if not tty and (done % 10 == 0 or done == total):
            print(f"acquired {done}/{total} poses", flush=True)  # while the run goes on

    previous = {s: signal.signal(s, lambda *_: stop.update(requested=True))
                for s in (signal.SIGINT, signal.SIGTERM)}  # fmt: skip
    try:
        with bar:
            run_acquisition(opened.manipulator, opened.cameras, opened.clock, d, todo,
                            opened.board, writer.store, config=config,
                            should_stop=lambda: stop["requested"], sensors=opened.sensors,
                            progress=progress)  # fmt: skip
    except RunStoppedError as exc:
        raise RunStoppedError(f"run stopped ({exc}); {len(writer.done)} of {len(pose_ids)} "
                              f"poses stored; resume with: {resume_hint}") from None  # fmt: skip
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    mean_settle = float(np.mean(settles)) if settles else 0.0
    size_mb = writer.size_bytes() / 1e6
    settle = "vision" if config.settle == "vision" else f"fixed:{config.fixed_s:g}"
    yield (f"stored {len(writer.done)} of {len(pose_ids)} poses in {writer.run_dir} "
           f"({size_mb:.1f} MB); mean settle {mean_settle:.2f} s ({settle})")  # fmt: skip
    for pose, reason in failed:
        yield f"pose {pose} failed: {reason}"
