"""Runs started from the station page: the cameras' calibration, an acquisition, a check.

A :class:`StationRuns` runs them on the devices the :class:`~microcal.workflows.live.LiveStation`
has open (the page's rig, never a second one), one at a time and never during a move (they
share the station's worker), and keeps what the page shows of the run under way: its stage,
``done`` of ``total`` from the procedures' progress callbacks (the views of the cameras'
calibration, the poses of an acquisition, the check poses), and how it ended, in words.

Cancel asks the run to stop at the end of the step under way (a view, a pose): an acquisition
stops through its ``should_stop`` exactly as Ctrl-C stops ``microcal acquire``, every pose
before stored and the run directory locked no longer, so that it resumes from the page or
with ``microcal acquire --out RUN --resume``. A cancelled check writes nothing; a cancelled
cameras' calibration writes no cameras.json (its views are replaced by the next one).

Every run writes under one directory (by default ``station-runs`` beside the calibration),
each in a folder the page names with a plain word: the page never names a path.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import InputError, MicrocalError
from .live import LiveStation

__all__ = ["RUN_KINDS", "RunCancelledError", "RunProgress", "StationRuns"]

#: What the page can start: the cameras' calibration, an acquisition, a check.
RUN_KINDS = ("cameras", "acquire", "check")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class RunCancelledError(MicrocalError):
    """The page's cancel ended a run between two of its steps."""


@dataclass
class RunProgress:
    """A run of the page: what it is, how far it got, how it ended.

    Attributes
    ----------
    kind : str
        One of :data:`RUN_KINDS`.
    status : str
        ``running``, ``done``, ``cancelled``, ``stopped`` (a device stopped it) or ``failed``.
    stage : str
        What it does now, in words.
    done, total : int
        Steps done of the steps to do (0 of 0 before the first is known).
    message : str
        How it ended (or what it said last), one line.
    out : str
        Where it writes.
    resume : str
        The command that resumes it (an acquisition that did not finish), else empty.
    took_s : float
        Wall time so far, s.
    """

    kind: str
    status: str = "running"
    stage: str = "starting"
    done: int = 0
    total: int = 0
    message: str = ""
    out: str = ""
    resume: str = ""
    took_s: float = 0.0
    started: float = field(default_factory=time.monotonic)

    def as_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        took = time.monotonic() - self.started if self.status == "running" else self.took_s
        return {"kind": self.kind, "status": self.status, "stage": self.stage, "done": self.done,
                "total": self.total, "message": self.message, "out": self.out,
                "resume": self.resume, "took_s": round(took, 1)}  # fmt: skip


def _stamp() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%S")


def _frames_option(kind: str, opts: Mapping[str, object]) -> int | None:
    """The ``frames`` option of a run (None: the command's default).

    Raises
    ------
    InputError
        Frames that are not a whole number from 1 to 100 (1000 for a check).
    """
    from ..formats.records import MAX_FRAMES_PER_POSE

    frames = opts.get("frames")
    if frames is None:
        return None
    most = 1000 if kind == "check" else MAX_FRAMES_PER_POSE
    per = "view" if kind == "cameras" else "pose"
    if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= most:
        raise InputError(
            f"frames: expected a whole number from 1 to {most} per {per}, got {frames!r}"[:200]
        )
    return frames


class StationRuns:
    """Runs of the page on a :class:`LiveStation`'s devices (module docstring).

    Parameters
    ----------
    live : LiveStation
        Opened with its rig's spec and its calibration's path (:func:`open_live_station`).
    root : path, optional
        Where runs write (default: ``station-runs`` beside the calibration).
    """

    def __init__(self, live: LiveStation, root: Path | None = None) -> None:
        if live.calibration_path is None:
            raise InputError("runs: the station was opened without its calibration's path")
        self.live = live
        self.root = root or live.calibration_path.with_name("station-runs")
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self._run: RunProgress | None = None
        self._poses_default = 12

    # --- what the page asks --------------------------------------------------------------

    def state(self) -> dict[str, Any] | None:
        """The last run's progress (None before the first)."""
        with self._lock:
            return None if self._run is None else self._run.as_dict()

    def cancel(self) -> bool:
        """Ask the run under way to stop after its current step; False when none runs."""
        with self._lock:
            running = self._run is not None and self._run.status == "running"
            if running:
                self._cancel.set()
                assert self._run is not None
                self._run.stage = "cancelling (after the step under way)"
        return running

    def start(self, kind: str, options: Mapping[str, object] | None = None) -> RunProgress:
        """Start a run in the station's worker; returns at once (see :meth:`state`).

        Parameters
        ----------
        kind : str
            ``cameras``, ``acquire`` or ``check``.
        options : mapping
            ``name`` (the run's folder, a plain word; a new one by default), for an
            acquisition ``poses`` (12 to 2000, a new run) or ``resume`` (true: continue the
            run ``name``), and ``frames`` (per camera and pose of an acquisition or a check,
            up to 100 and 1000, or per camera and view of the cameras' calibration, up to
            100; the command's default when left out).

        Raises
        ------
        InputError
            An unknown kind, a bad option, a run or move under way (``busy: ...``), a rig
            without what the run needs; nothing has started.
        """
        opts = dict(options or {})
        if kind not in RUN_KINDS:
            raise InputError(f"run: expected one of {', '.join(RUN_KINDS)}, got {kind!r}"[:200])
        name = opts.get("name") or f"{kind}-{_stamp()}"
        if not isinstance(name, str) or not _NAME.match(name):
            raise InputError(
                f"name: expected a plain word (letters, digits, . _ -), got {name!r}"[:200]
            )
        unknown = sorted(set(opts) - {"name", "poses", "resume", "frames"})
        if unknown:
            raise InputError(f"run: unknown option(s) {', '.join(unknown)}"[:200])
        frames = _frames_option(kind, opts)
        if kind in ("acquire", "check") and len(self.live.models) < 2:
            raise InputError(
                f"{kind}: this station has one camera; the tip's depth is measured with two "
                "or more (the commands take a rig with them)"
            )
        work: Callable[[RunProgress], None]
        if kind == "acquire":
            work = self._acquisition(self.root / name, opts, frames)
        elif kind == "check":
            work = self._check(self.root / "checks" / f"{name}.json", frames)
        else:
            work = self._cameras(self.root / name, frames)
        run = RunProgress(kind)
        label = {"cameras": "calibrating the cameras", "acquire": "acquiring",
                 "check": "checking the calibration"}[kind]  # fmt: skip
        with self._lock:
            before, self._run = self._run, run
        self._cancel.clear()
        try:
            self.live._start(label, lambda: self._execute(run, work))
        except BaseException:
            with self._lock:
                self._run = before
            raise
        return run

    # --- running ---------------------------------------------------------------------------

    def _tick(self, run: RunProgress, stage: str) -> Callable[[int, int], None]:
        def tick(done: int, total: int) -> None:
            with self._lock:
                run.stage, run.done, run.total = stage, done, total
            if self._cancel.is_set() and done < total:
                raise RunCancelledError(f"cancelled after {done} of {total}")

        return tick

    def _execute(self, run: RunProgress, work: Callable[[RunProgress], None]) -> None:
        from ..procedures.acquisition import RunStoppedError

        status, message = "done", ""
        try:
            work(run)
        except RunCancelledError as exc:
            status, message = "cancelled", str(exc)
        except RunStoppedError as exc:
            cancelled = self._cancel.is_set()
            status, message = ("cancelled" if cancelled else "stopped"), str(exc)
        except MicrocalError as exc:
            status, message = "failed", str(exc)
            if self.live.manipulator.halted:
                status, message = "stopped", f"stopped by the stop control ({exc})"
        except Exception as exc:  # a device's unforeseen failure: in words, the server goes on
            status, message = "failed", f"unexpected {type(exc).__name__}: {exc}"
        finally:
            self.live.station.rig.look_at()
        with self._lock:
            run.status, run.took_s = status, time.monotonic() - run.started
            if message:
                run.message = message
            if status != "done":
                run.stage = status

    def _acquisition(
        self, out: Path, opts: Mapping[str, object], frames: int | None
    ) -> Callable[[RunProgress], None]:
        from ..formats.run_directory import RunDirectory
        from .acquire import AcquireRequest, check_out, check_same_rig

        spec = self.live.spec
        if spec is None:
            raise InputError("acquire: the station was opened without its rig's spec")
        resume = opts.get("resume", False)
        if not isinstance(resume, bool):
            raise InputError(f"resume: expected true or false, got {resume!r}"[:200])
        poses = opts.get("poses", self._poses_default)
        if isinstance(poses, bool) or not isinstance(poses, int):
            raise InputError(f"poses: expected a whole number, got {poses!r}"[:200])
        rig = self.live.station.rig
        request = AcquireRequest(out, rig="page", poses=None if resume else poses, resume=resume,
                                 frames=frames, manipulator=rig.selected)  # fmt: skip
        check_out(out, resume, False)
        manifest = RunDirectory(out).manifest if resume else None
        if manifest is not None:
            check_same_rig(out, manifest.rig, spec.to_dict())
        req = request.filled(manifest)
        if manifest is None:
            from ..procedures.planning import check_poses

            check_poses(str(req.design), int(poses))
        return lambda run: self._acquire(run, out, req, manifest is None)

    def _acquire(self, run: RunProgress, out: Path, req: Any, new: bool) -> None:
        from ..formats.run_lock import run_lock
        from ..procedures.acquisition import AcquisitionConfig
        from ..procedures.acquisition import acquire as run_acquisition
        from .acquire import _open_run, _run_directory, plan_for
        from .options import parse_settle

        rig = self.live.station.rig
        m = rig.manipulator
        spec = self.live.spec
        plan = None
        if new:
            plan = plan_for(str(req.design), int(req.poses), int(req.seed), m.limits_um, m.axes)
        mode, fixed_s = parse_settle(str(req.settle))
        config = AcquisitionConfig(settle=mode, fixed_s=fixed_s, frames_per_pose=int(req.frames),
                                   store_roi=req.store == "roi")  # fmt: skip
        hint = f"microcal acquire --out {out} --resume"
        with self._lock:
            run.out, run.resume = str(out), hint
        with _run_directory(out, creating=new), run_lock(out, "acquire"):
            writer, pose_ids, d = _open_run(out, spec, rig, plan, req)
            todo = writer.remaining(pose_ids)
            before = len(pose_ids) - len(todo)
            stage = "poses stored"
            with self._lock:
                run.stage, run.done, run.total = stage, before, len(pose_ids)

            def progress(done: int, total: int, record: Any) -> None:
                with self._lock:
                    run.done = before + done
                    if record.status != "ok":
                        run.message = f"pose {record.pose} failed: {record.reason or ''}"
                joints = record.reported_um or record.commanded_um
                self.live.show_joints(joints)  # the page's tip follows the run

            try:
                run_acquisition(m, rig.cameras, rig.clock, d, todo, rig.board, writer.store,
                                config=config, sensors=rig.sensors, progress=progress,
                                should_stop=self._cancel.is_set)  # fmt: skip
            except MicrocalError as exc:
                from ..procedures.acquisition import RunStoppedError

                text = str(exc).removeprefix("run stopped (").removesuffix(")")
                raise RunStoppedError(
                    f"{len(writer.done)} of {len(pose_ids)} poses stored ({text}); resume "
                    f"from the page or with: {hint}"
                ) from None
        with self._lock:
            run.resume = ""
            run.message = f"stored {len(writer.done)} of {len(pose_ids)} poses in {out}"

    def _check(self, out: Path, frames: int | None) -> Callable[[RunProgress], None]:
        from ..formats.check_file import CHECK_FORMAT
        from ..formats.json_file import check_json_output
        from ..procedures.check import CheckConfig

        check_json_output(out, CHECK_FORMAT, "check.json")
        cfg = CheckConfig() if frames is None else CheckConfig(frames=frames)
        return lambda run: self._run_check(run, out, cfg)

    def _run_check(self, run: RunProgress, out: Path, cfg: Any) -> None:
        from ..procedures.check import run_check
        from .check import check_reference, record_check

        live = self.live
        station = live.station
        calibration = live.calibration_path
        assert calibration is not None
        with self._lock:
            run.out = str(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        history = live.check_history()
        station.rig.look_at()
        tick = self._tick(run, "check poses measured")
        result = run_check(station.rig.manipulator, station.rig.clock,
                           station.probe.measure_with_covariance, station.calibration, config=cfg,
                           reference=check_reference(history), progress=tick)  # fmt: skip
        flag = record_check(calibration, out, station.calibration.name, result, history)
        live.refresh_health()
        off = ", ".join(f"{v:+.2f}" for v in result.offset_um)
        with self._lock:
            run.message = (f"verdict {result.verdict}, offset ({off}) µm; wrote {out}"
                           + (f"; {flag}" if flag else ""))  # fmt: skip

    def _cameras(self, out: Path, frames: int | None) -> Callable[[RunProgress], None]:
        from ..formats.cameras_file import CAMERAS_FORMAT
        from ..formats.json_file import check_json_output

        rig = self.live.station.rig
        if rig.target_stage is None or rig.calibration_target is None:
            raise InputError(
                "cameras: the rig has no target stage; add [target_stage] and "
                "calibration_target to the rig file (docs/hardware.md)"
            )
        cameras_json = check_json_output(out / "cameras.json", CAMERAS_FORMAT, "cameras.json")
        return lambda run: self._calibrate_cameras(run, cameras_json, frames)

    def _calibrate_cameras(self, run: RunProgress, cameras_json: Path, frames: int | None) -> None:
        from ..formats.cameras_file import save_stereo_calibration
        from ..formats.commands_csv import write_joint_csv
        from ..formats.images import write_tiff
        from ..procedures.rig_stereo import (
            RigViewsConfig,
            calibrate_on_rig,
            default_steps_um,
            view_name,
        )
        from .stereo import STEPS_FILE

        rig = self.live.station.rig
        stage, target = rig.target_stage, rig.calibration_target
        assert stage is not None
        assert target is not None
        views = cameras_json.with_name("cameras-views")
        files: dict[str, list[Path]] = {}
        with self._lock:
            run.out = str(cameras_json)

        def store(view: int, camera: str, frames: list) -> None:  # type: ignore[type-arg]
            views.mkdir(parents=True, exist_ok=True)
            files.setdefault(camera, []).append(write_tiff(views / view_name(camera, view), frames))

        steps = default_steps_um()
        tick = self._tick(run, "views grabbed")
        try:
            config = RigViewsConfig() if frames is None else RigViewsConfig(frames_per_view=frames)
            cal = calibrate_on_rig(stage, rig.cameras, rig.clock, target, steps, config=config,
                                   store=store, progress=tick)  # fmt: skip
        finally:
            # the tool's target in view again: the simulator and the twin show the calibration
            # target while its stage moved last, so the tool is told its place once more
            with contextlib.suppress(MicrocalError):  # halted: the stop control holds
                rig.manipulator.move_to_um(rig.manipulator.position_um())
                rig.manipulator.wait_until_stopped(rig.clock)
        steps_path = write_joint_csv(views / STEPS_FILE, steps)
        save_stereo_calibration(cameras_json, cal, files, steps_path, target.spec)
        with self._lock:
            run.stage = "calibrated"
            run.message = (f"{len(cal.cameras)} camera(s), RMS {cal.rms_px:.3f} px; wrote "
                           f"{cameras_json} (use it with microcal fit --cameras)")  # fmt: skip
