"""``microcal acquire`` on a one-camera rig: the acquisition that measures as it goes.

A rig of one camera on a focus drive (the simulated ``preset = "patch"``, or a hardware rig
with one camera and a ``[microscope]`` naming its focus) cannot measure a tip in 3D from
stored images afterwards: its depth is found by moving the focus at the pose. So the tip is
measured during the acquisition (:func:`~microcal.procedures.one_camera_acquisition.
acquire_one_camera`: a focus sweep at each pose, the focus following the tip through the
working volume), in the microscope's frame {M} of the scope calibration
(``--scope scope.json --objective 40x``, from ``microcal scope-calibrate``), and the run
directory (:mod:`microcal.formats.one_camera_run`) holds no images: its ``measurements.csv``,
rewritten after every pose, is what ``microcal fit RUN`` fits.

The run is crash-safe: each pose's line is on disk before the next pose begins, and
``microcal acquire --out RUN --resume`` takes the stored poses as measured and goes on with
the poses the design asks for next (the same ones: they follow from the seed and the tips).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validation import FloatArray
from ..devices.rig_spec import HardwareRigSpec, RigSpec, SimRigSpec
from ..errors import InputError
from ..formats.one_camera_run import (
    ONE_CAMERA_FILE,
    POSES_FILE,
    is_one_camera_run,
    read_one_camera_setup,
    write_one_camera_run,
)
from ..formats.run_directory import MANIFEST, RunDirectory
from ..formats.run_lock import LOCK_NAME
from ..journal_record import JournalRecord
from ..json_value import JsonValue
from ..procedures.one_camera_acquisition import DEFAULT_VOLUME_HALF_UM, OneCameraPose, OneCameraRun
from ..procedures.one_camera_setup import DEFAULT_APPROACH_DEG
from ..procedures.planning import MIN_DESIGN_POSES

__all__ = [
    "DEFAULT_ONE_CAMERA_POSES",
    "DEFAULT_ONE_CAMERA_SETTLE",
    "check_one_camera_rig",
    "is_one_camera_rig",
    "refuse_one_camera_options",
    "run_one_camera_acquire",
    "wants_one_camera",
]

#: Poses of a one-camera run when ``--poses`` is left out (the patch demo's).
DEFAULT_ONE_CAMERA_POSES = 80
#: The wait after the manipulator reports stopped when ``--settle`` is left out.
DEFAULT_ONE_CAMERA_SETTLE = "fixed:1"
_NOT_HERE = ("design", "frames", "store", "check_calibration", "check_every", "until_um",
             "max_poses", "cameras")  # fmt: skip


def wants_one_camera(request: Any) -> bool:
    """Whether an acquire request is a one-camera run: ``--scope`` given, or a resume of one."""
    return request.scope is not None or (request.resume and is_one_camera_run(request.out))


def is_one_camera_rig(spec: RigSpec) -> bool:
    """A rig of one camera on a focus drive: the simulated ``patch`` preset, or hardware
    with one camera and a ``[microscope]``."""
    from ..sim.platforms import ONE_CAMERA_PRESET

    if isinstance(spec, SimRigSpec):
        return spec.preset == ONE_CAMERA_PRESET
    return (isinstance(spec, HardwareRigSpec) and spec.microscope is not None
            and len(spec.cameras) == 1)  # fmt: skip


def refuse_one_camera_options(request: Any) -> None:
    """Refuse, in one line, a one-camera rig without ``--scope`` and the one-camera options
    without it (a run of the cameras' images)."""
    from ..formats.rig_file import load_rig

    given = [n for n in ("objective", "volume_um", "approach_deg", "azimuth_deg")
             if getattr(request, n) is not None]  # fmt: skip
    if given:
        flags = ", ".join("--" + n.replace("_", "-") for n in given)
        raise InputError(f"{flags}: for a one-camera run only; give its scope calibration "
                         "with --scope scope.json")  # fmt: skip
    if not request.resume and is_one_camera_rig(load_rig(str(request.rig or "sim"))):
        raise InputError(
            f"--rig {request.rig}: one camera on a focus drive measures each tip as it acquires, "
            "in the microscope's frame; give --scope scope.json --objective 40x (made by "
            "microcal scope-calibrate)"
        )


def check_one_camera_rig(spec: RigSpec, name: str) -> None:
    """Refuse, in one line, a rig a one-camera run cannot use (before any device opens)."""
    if isinstance(spec, SimRigSpec) and not is_one_camera_rig(spec):
        raise InputError(
            f"--rig {name}: preset {spec.preset} has cameras around the manipulator, not one "
            'camera on a focus drive; use preset = "patch", or leave --scope out'
        )
    if isinstance(spec, HardwareRigSpec):
        if len(spec.cameras) != 1:
            raise InputError(
                f"--rig {name}: a one-camera run needs a rig of one camera, this one has "
                f"{len(spec.cameras)} ({', '.join(spec.cameras)})"
            )
        if spec.microscope is None or spec.microscope.focus is None:
            raise InputError(
                f"--rig {name}: a one-camera rig measures depth with its focus drive; name it "
                'in a [microscope] table (xy_stage = "...", focus = "...": Micro-Manager devices)'
            )


@dataclass(frozen=True)
class _Setup:
    """What the poses follow from (``one_camera.json``)."""

    scope: dict[str, JsonValue]  # file, objective and the set itself
    volume_half_um: list[float]
    poses: int
    seed: int
    settle_s: float
    approach_deg: float
    azimuth_deg: float
    joint_origin_um: list[float] | None = None
    start_focus_um: float | None = None

    def to_json(self) -> dict[str, JsonValue]:
        return {
            "scope": self.scope, "volume_centre_um": [0.0, 0.0, 0.0],
            "volume_half_um": list(self.volume_half_um), "poses": self.poses, "seed": self.seed,
            "settle_s": self.settle_s, "approach_deg": self.approach_deg,
            "azimuth_deg": self.azimuth_deg, "joint_origin_um": self.joint_origin_um,
            "start_focus_um": self.start_focus_um, "method": "sweep",
        }  # fmt: skip


def _volume(text: str | None) -> list[float]:
    if text is None:
        return list(DEFAULT_VOLUME_HALF_UM)
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) and v > 0 for v in values):
        raise InputError(
            f"--volume-um: expected three half sizes > 0 in µm, X,Y,Z (e.g. 100,100,25), "
            f"got {text!r}"
        )
    return values


def _new_setup(request: Any) -> _Setup:
    """A new run's setup from its options, each checked (one line each)."""
    from ..formats.scope_file import load_objective, objective_names
    from .options import parse_settle

    for name in _NOT_HERE:
        if getattr(request, name) is not None:
            flag = "--" + name.replace("_", "-")
            raise InputError(f"{flag}: not for a one-camera run (it designs its poses in the "
                             f"working volume, --volume-um, and measures as it goes)")  # fmt: skip
    if request.scope is None:
        raise InputError(
            "a one-camera run measures in the microscope's frame: give --scope scope.json "
            "--objective 40x (made by microcal scope-calibrate)"
        )
    if request.objective is None:
        held = ", ".join(objective_names(request.scope))
        raise InputError(f"--objective: name the set of {request.scope} to use (it holds {held})")
    record = load_objective(request.scope, request.objective)
    poses = DEFAULT_ONE_CAMERA_POSES if request.poses is None else int(request.poses)
    if poses < MIN_DESIGN_POSES:
        raise InputError(f"--poses: a one-camera run needs {MIN_DESIGN_POSES} or more, got {poses}")
    mode, settle_s = parse_settle(request.settle or DEFAULT_ONE_CAMERA_SETTLE)
    if mode != "fixed":
        raise InputError("--settle vision: a one-camera run waits a fixed time; give fixed:SECONDS")
    scope: dict[str, JsonValue] = {"file": str(request.scope), "objective": request.objective,
                                   "set": record}  # fmt: skip
    approach = DEFAULT_APPROACH_DEG if request.approach_deg is None else request.approach_deg
    azimuth = 0.0 if request.azimuth_deg is None else request.azimuth_deg
    return _Setup(scope, _volume(request.volume_um), poses, int(request.seed or 0), settle_s,
                  float(approach), float(azimuth))  # fmt: skip


def _resumed_setup(request: Any) -> _Setup:
    """A stopped run's setup (one_camera.json); options given again must agree with it."""
    raw = read_one_camera_setup(request.out)
    given = {"poses": request.poses, "seed": request.seed, "approach_deg": request.approach_deg,
             "azimuth_deg": request.azimuth_deg}  # fmt: skip
    for key, value in given.items():
        if value is not None and value != raw[key]:
            flag = "--" + key.replace("_", "-")
            raise InputError(f"{flag} {value}: this run was begun with {raw[key]} "
                             f"({ONE_CAMERA_FILE}); leave it out to resume")  # fmt: skip
    if request.scope is not None or request.volume_um is not None:
        raise InputError(f"--scope and --volume-um: a resumed run uses its own "
                         f"({request.out / ONE_CAMERA_FILE}); leave them out")  # fmt: skip
    keys = ("scope", "volume_half_um", "poses", "seed", "settle_s", "approach_deg",
            "azimuth_deg", "joint_origin_um", "start_focus_um")  # fmt: skip
    return _Setup(**{k: raw[k] for k in keys})  # type: ignore[arg-type]


def _spec_for(request: Any) -> RigSpec:
    from ..formats.rig_file import load_rig, rig_from_record
    from .acquire import _simulated_record, check_same_rig

    if not request.resume:
        return load_rig(str(request.rig or "sim"))
    manifest = RunDirectory(request.out).manifest
    if manifest is None:
        raise InputError(f"{request.out}: no run to resume (no {MANIFEST})")
    if request.rig is None:
        spec = rig_from_record(_simulated_record(request.out, manifest),
                               str(request.out / MANIFEST))  # fmt: skip
    else:
        spec = load_rig(str(request.rig))
    check_same_rig(request.out, manifest.rig, spec.to_dict())
    return spec


def run_one_camera_acquire(request: Any) -> Iterator[str]:
    """``microcal acquire`` on a one-camera rig (module docstring); yields the lines to print.

    Raises
    ------
    MicrocalError
        A bad option, no scope set, a rig without one camera and a focus drive, a run
        directory that does not fit, or a run stopped (with the command that resumes it).
    """
    from .acquire import check_out

    out = Path(request.out)
    if request.dry_run and request.resume:
        raise InputError("--dry-run and --resume: choose one")
    check_out(out, request.resume, bool(request.dry_run))
    setup = _resumed_setup(request) if request.resume else _new_setup(request)
    spec = _spec_for(request)
    check_one_camera_rig(spec, str(request.rig or "sim"))
    if request.dry_run:
        yield from _dry_run(request, spec, setup)
        return
    made = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        yield from _acquire(out, request, spec, setup)
    except BaseException:
        poses = out / POSES_FILE
        if not request.resume and not (poses.is_file() and poses.stat().st_size > 0):
            _remove_new_run(out, made)  # nothing stored: no run left half made
        raise


def _dry_run(request: Any, spec: RigSpec, setup: _Setup) -> Iterator[str]:
    """The rig checked without moving anything (one frame; the volume within the limits)."""
    from ..procedures.one_camera_dry_run import one_camera_dry_run
    from ..procedures.one_camera_setup import nominal_axes_um
    from .rigs import open_rig

    with open_rig(spec, request.manipulator) as rig:
        (_, camera), = rig.cameras.items()  # fmt: skip
        assert rig.microscope is not None  # checked by check_one_camera_rig
        lines = one_camera_dry_run(
            rig.manipulator, rig.microscope, camera, _tip_of(rig),
            np.array(setup.volume_half_um), nominal_axes_um(setup.approach_deg,
                                                            setup.azimuth_deg), setup.poses,
        )  # fmt: skip
        description = [f"{what}: {text}" for what, text in (rig.description or {}).items()]
    scope = setup.scope
    yield from description
    yield f"scope calibration: {scope['file']}, objective {scope['objective']}"
    yield from lines


def _remove_new_run(out: Path, made: bool) -> None:
    with contextlib.suppress(OSError):
        for name in (MANIFEST, ONE_CAMERA_FILE, POSES_FILE, "measurements.csv", LOCK_NAME):
            (out / name).unlink(missing_ok=True)
        if made and not any(out.iterdir()):
            out.rmdir()


def _acquire(out: Path, request: Any, spec: RigSpec, setup: _Setup) -> Iterator[str]:
    from ..devices.microscope_drive import MicroscopeDrive
    from ..devices.shifted_joints import ShiftedJoints
    from ..formats.pose_journal import PoseJournal
    from ..formats.run_lock import run_lock
    from ..procedures.one_camera_acquisition import WorkingVolume, acquire_one_camera
    from ..procedures.one_camera_setup import nominal_axes_um
    from .rigs import open_rig

    with open_rig(spec, request.manipulator) as rig, run_lock(out, "acquire"):
        (name, camera), = rig.cameras.items()  # fmt: skip
        assert rig.microscope is not None  # checked by check_one_camera_rig
        finder = _finder(rig, camera, setup)
        drive = MicroscopeDrive(rig.microscope, camera, rig.clock)
        if setup.joint_origin_um is None:  # a new run: its joints counted from here
            origin = [float(v) for v in np.round(rig.manipulator.position_um(), 0)]
            setup = _Setup(**{**setup.__dict__, "joint_origin_um": origin,
                              "start_focus_um": drive.focus_um})  # fmt: skip
            write_one_camera_run(out, _manifest(spec, rig, name, setup), setup.to_json())
            journal = PoseJournal(out / POSES_FILE)
            lines: list[dict[str, JsonValue]] = []
        else:
            journal, lines = PoseJournal.resume(out / POSES_FILE)
        done = [_pose_of(line) for line in lines]
        stored = list(done)
        device = ShiftedJoints(rig.manipulator, np.array(setup.joint_origin_um, dtype=float))
        verb = "resuming" if request.resume else "starting"
        yield f"{verb} {out}: {setup.poses - len(done)} of {setup.poses} poses to do (one camera)"

        def store(record: JournalRecord, tip: OneCameraPose) -> None:
            journal.append({"record": record.to_json(), "tip": tip.to_json()})
            stored.append((record, tip))
            _write_measurements(out, stored)

        try:
            run = acquire_one_camera(
                device, rig.clock, drive.move_focus, drive.grab, finder,
                WorkingVolume(np.zeros(3), np.array(setup.volume_half_um)), setup.poses,
                nominal_um_per_um=nominal_axes_um(setup.approach_deg, setup.azimuth_deg),
                start_focus_um=float(setup.start_focus_um or 0.0), settle_s=setup.settle_s,
                seed=setup.seed, store=store, done=done, progress=_progress,
            )  # fmt: skip
        except KeyboardInterrupt:
            from ..procedures.acquisition import RunStoppedError

            raise RunStoppedError(f"run stopped; {len(stored)} poses stored; resume with: "
                                  f"microcal acquire --out {out} --resume",
                                  interrupted=True) from None  # fmt: skip
        _write_measurements(out, stored)
    yield from _summary(out, run)


def _tip_of(rig: Any) -> Any:
    """The rig's tool's tip (InputError, one line, for a rig whose target is a board)."""
    from ..vision.tip_target import TipTarget

    if not isinstance(rig.board, TipTarget):
        raise InputError(f"the rig's target is {rig.board.spec}, not a tool's tip: a one-camera "
                         f"run follows a pipette's tip (board = \"tip:pipette:10:1\")")  # fmt: skip
    return rig.board


def _finder(rig: Any, camera: Any, setup: _Setup) -> Any:
    from ..procedures.one_camera_setup import tool_finder
    from ..vision.microscope_frame import MicroscopeFrame

    _tip_of(rig)
    record = setup.scope["set"]
    assert isinstance(record, dict)
    frame = MicroscopeFrame.from_record(record, camera.sensor_size_px)
    return tool_finder(frame, setup.approach_deg, setup.azimuth_deg, rig.board.tip_um / 2.0)


def _manifest(spec: RigSpec, rig: Any, camera: str, setup: _Setup) -> dict[str, Any]:
    from ..formats.run_manifest import new_manifest

    return new_manifest(
        rig=spec.to_dict(), target=rig.board.spec, cameras=[camera],
        design={"kind": "one-camera", "poses": setup.poses, "seed": setup.seed},
        settle=f"fixed:{setup.settle_s:g}", frames_per_pose=13, store="none",
        command="acquire", device=rig.manipulator.identity, manipulator=rig.selected,
    )  # fmt: skip


def _progress(done: int, total: int) -> None:
    if done % 10 == 0 or done == total:
        print(f"acquired and measured {done}/{total} poses", flush=True)


def _pose_of(line: dict[str, JsonValue]) -> tuple[JournalRecord, OneCameraPose]:
    """A stored pose from its journal line."""
    from ..errors import FormatError
    from ..kinematics.extra_inputs import APPROACH_INPUTS, extra_input

    r: Any = line.get("record")
    t: Any = line.get("tip")
    try:
        columns = [extra_input(a).column for a in APPROACH_INPUTS]
        record = JournalRecord(
            int(r["pose"]), [float(v) for v in r["commanded_um"]], {c: r.get(c) for c in columns},
            r["status"], r["time"], r["sim_time_s"], r["move_s"], r["settle_s"],
            r.get("residual_px"), r.get("reported_um"), r.get("reason"),
        )  # fmt: skip
        found = t["p_um"] is not None
        p = np.array(t["p_um"], float) if found else np.full(3, np.nan)
        cov = np.array(t["cov_um2"], float) if found else np.full((3, 3), np.nan)
        tip = OneCameraPose(int(t["pose"]), p, cov, int(t["frames"]), float(t["seconds"]))
    except (KeyError, TypeError, ValueError, AttributeError):
        raise FormatError(f"{POSES_FILE}: a pose's line lacks its record or tip; start a new "
                          "run") from None  # fmt: skip
    return record, tip


def _write_measurements(out: Path, stored: list[tuple[JournalRecord, OneCameraPose]]) -> None:
    """measurements.csv of the poses stored: joints, the tip in {M} and its covariance."""
    from ..formats.measurements import write_measurements
    from ..kinematics.extra_inputs import APPROACH_INPUTS, extra_input

    records = [r for r, _ in stored]
    run = OneCameraRun(np.array([r.commanded_um for r in records]), [t for _, t in stored],
                       records)  # fmt: skip
    cov = run.cov_um2
    std: FloatArray = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    extra = {a: np.array([r.approach.get(extra_input(a).column) or np.nan for r in records])
             for a in APPROACH_INPUTS}  # fmt: skip
    write_measurements(
        out / "measurements.csv", run.d_um, run.p_um, std_um=std, cov_um2=cov,
        status=[r.status for r in records], reason=[r.reason or "" for r in records],
        extra=extra, pose=[r.pose for r in records],
    )  # fmt: skip


def _summary(out: Path, run: OneCameraRun) -> Iterator[str]:
    ok = int(run.ok.sum())
    yield (f"stored {len(run.tips)} poses in {out} ({ok} tips measured, in the microscope's "
           f"frame {{M}}: measurements.csv); next: microcal fit {out}")  # fmt: skip
    for r in run.records:
        if r.status != "ok":
            yield f"pose {r.pose} failed: {r.reason}"
