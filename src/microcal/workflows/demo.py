"""``microcal demo``: its directory, its run's start and the files it writes beside the run.

The run itself (run.json, commands.csv, journal.jsonl, images/) is written while the demo
acquires (:class:`~microcal.formats.run_directory.RunWriter`, started by
:func:`start_demo_run`); :func:`write_demo_outputs` writes what it derived: measurements,
cameras, models, results and the report.
"""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..devices.rig_spec import SimRigSpec
from ..errors import InputError
from ..formats.check_file import history_path
from ..formats.file_lock import lock_path
from ..formats.outputs import check_writable
from ..formats.run_directory import RUN_FILE_NAMES, RunDirectory, RunWriter
from ..formats.run_lock import LOCK_NAME
from ..formats.run_manifest import new_manifest
from .demo_results import fit_sections

if TYPE_CHECKING:
    from ..experiments.demo import DemoResult
    from ..experiments.station_demo import StationDemoResult

__all__ = [
    "DEMO_FILES",
    "DemoRequest",
    "check_demo_dir",
    "clear_demo_dir",
    "demo",
    "run_station_demo_files",
    "start_demo_run",
    "start_station_demo",
    "write_demo_outputs",
    "write_station_outputs",
]

#: The demo's last stage in its time table (results.json ``timing.stages_s``): writing the
#: measurements, cameras, calibration, results and the report.
OUTPUT_STAGE = "files and report"
#: What a demo writes into its directory (and may replace on the next demo).
DEMO_FILES = frozenset(RUN_FILE_NAMES)
#: Files other microcal commands write into a demo's directory afterwards (the history that
#: ``check`` keeps beside calibration.json, ``fit --mat``'s export, a lock left by a process
#: that was killed): replaced with the demo, whose calibration they belonged to.
LATER_FILES = frozenset(
    {
        history_path("calibration.json").name,
        "calibration.mat",
        LOCK_NAME,
        *(
            lock_path(name).name
            for name in (*RUN_FILE_NAMES, history_path("calibration.json").name)
        ),
    }
)


def write_demo_outputs(out: Path, result: DemoResult, wall_s: float) -> None:
    """Write measurements.csv, cameras.json, calibration.json, results.json and report.html.

    Parameters
    ----------
    out : Path
        The demo's run directory.
    result : DemoResult
        What the demo measured and identified.
    wall_s : float
        Wall-clock seconds the demo took (``timing.wall_s`` of results.json).
    """
    from ..formats.calibration_file import Calibration, write_calibration
    from ..formats.cameras_file import cameras_to_dict, write_cameras
    from ..formats.provenance import provenance
    from ..formats.results_file import update_results
    from ..procedures.rig_time import RigTime
    from ..report import write_report

    out.mkdir(parents=True, exist_ok=True)
    poses = list(range(1, len(result.d_um) + 1))
    RunDirectory(out).write_measurements(poses, result.d_um, result.measurements)
    prov = provenance(command="demo", seed=result.seed)
    cameras = cameras_to_dict(result.calibration, prov)
    write_cameras(out / "cameras.json", cameras)
    if result.manipulator is None:
        raise InputError("demo: nothing was identified; no calibration to write")
    entry = result.manipulator
    write_calibration(
        out / "calibration.json", Calibration({entry.name: entry}, cameras["cameras"], prov)
    )
    results_path = out / "results.json"
    results_path.unlink(missing_ok=True)
    records = result.records
    update_results(results_path, {
        "stereo": {n: {"rms_px": c.rms_px, "model": c.model.kind}
                   for n, c in result.calibration.cameras.items()},
        **fit_sections(result, records,
                       {"mean_settle_s": float(np.mean([r.settle_s for r in records]))}),
        **result.evaluation.to_json(),
        "rig_time": RigTime.of_records([r.sim_time_s for r in records],
                                       [r.move_s for r in records],
                                       [r.settle_s for r in records]).to_json(),
        "timing": {"simulated_s": result.sim_time_s, "wall_s": wall_s,
                   "stages_s": dict(result.stages_s)},
        "provenance": prov,
    })  # fmt: skip
    write_report(out, forked=True)  # a command's own process: figures drawn on both cores


def write_station_outputs(out: Path, result: StationDemoResult, wall_s: float) -> None:
    """Write a station demo's files: each device's as :func:`write_demo_outputs` does, in
    ``out/NAME``, and in ``out`` the station's calibration.json (every device, the cameras),
    cameras.json, results.json (``devices``: each device's results; ``meet``: the meet
    tests by mode) and report.html (the devices side by side, linking their reports)."""
    import json

    from ..formats.atomic import write_text_atomic
    from ..formats.calibration_file import (
        Calibration,
        load_calibration,
        write_calibration,
    )
    from ..formats.provenance import provenance
    from ..formats.results_file import update_results

    devices: dict[str, object] = {}
    entries = {}
    for name, device in result.devices.items():
        write_demo_outputs(out / name, device, wall_s)
        data = json.loads((out / name / "results.json").read_text(encoding="utf-8"))
        devices[name] = {k: v for k, v in data.items() if k not in ("format", "provenance")}
        entries[name] = load_calibration(out / name / "calibration.json").manipulators[name]
    first = next(iter(result.devices))
    cameras = load_calibration(out / first / "calibration.json").cameras
    prov = provenance(command="demo", seed=next(iter(result.devices.values())).seed,
                      preset="thesis-platform")  # fmt: skip
    write_calibration(out / "calibration.json", Calibration(entries, cameras, prov))
    write_text_atomic(
        out / "cameras.json", (out / first / "cameras.json").read_text(encoding="utf-8")
    )
    results_path = out / "results.json"
    results_path.unlink(missing_ok=True)
    update_results(results_path, {
        "devices": devices,
        "meet": {mode: m.as_dict() for mode, m in result.meet.items()},
        "timing": {"simulated_s": result.sim_time_s, "wall_s": wall_s},
        "provenance": prov,
    })  # fmt: skip
    from ..report import write_report

    write_report(out)


@dataclass(frozen=True)
class DemoRequest:
    """What ``microcal demo`` is asked (the single-device presets).

    Attributes
    ----------
    out : Path
        The run directory (new, empty, or an earlier demo's, which is replaced).
    poses, frames_per_pose : int
        The acquisition's size.
    quick : bool
        Fewer frames per calibration view, one ISO cycle, fewer decoupling samples.
    camera_model : str
        ``pinhole``, ``affine`` or ``auto``.
    """

    out: Path
    seed: int = 0
    poses: int = 170
    frames_per_pose: int = 5
    quick: bool = False
    preset: str = "thesis"
    camera_model: str = "auto"


def demo(
    request: DemoRequest,
    progress: Any = None,
    started: Callable[[], None] | None = None,
    wall0_s: float | None = None,
) -> DemoResult:
    """``microcal demo``: check and start the run directory, run the demo on the simulated
    platform, write what it derived; ``started()`` is called once the directory is ready.

    ``wall0_s``: when the command started (``time.monotonic``; now by default).
    """
    import time

    from ..experiments.demo import demo_family, run_demo
    from ..experiments.stage_clock import StageClock
    from ..formats.results_file import update_results

    wall0 = time.monotonic() if wall0_s is None else wall0_s
    r = request
    stages = StageClock()
    with stages.stage("start"):
        plat, writer = start_demo_run(r.out, r.seed, r.poses, r.frames_per_pose, r.preset)
    if started is not None:
        started()
    result = run_demo(
        seed=r.seed, poses=r.poses, frames_per_pose=r.frames_per_pose, progress=progress,
        frames_per_view=4 if r.quick else 8, cycles=1 if r.quick else 3,
        decoupling_samples=5 if r.quick else 17, store=writer.store, plat=plat,
        camera_model=r.camera_model, family=demo_family(r.preset), stages=stages,
    )  # fmt: skip
    with stages.stage(OUTPUT_STAGE):
        write_demo_outputs(r.out, result, wall_s=time.monotonic() - wall0)
    result.stages_s = dict(stages.stages_s)
    # the files' own stage is known only once they are written: added to results.json after,
    # with the wall time so far (the command's start-up included)
    timing = {"stages_s": result.stages_s, "wall_s": time.monotonic() - wall0}
    update_results(r.out / "results.json", {"timing": timing})
    return result


def run_station_demo_files(
    out: Path,
    seed: int,
    progress: Any,
    wall0_s: float,
    **options: Any,
) -> StationDemoResult:
    """``microcal demo --preset thesis-platform``: check ``out``, run the station demo with
    each device's run written as it goes, then write the station's files.

    ``options``: ``poses``, ``frames_per_pose`` and the rest of
    :func:`~microcal.experiments.station_demo.run_station_demo`'s keywords; ``wall0_s`` is
    when the command started (``time.monotonic``).
    """
    import time

    from ..experiments.station_demo import run_station_demo

    fixed = options.get("fixed_settle_s")
    settle = "vision" if fixed is None else f"fixed:{fixed:g}"
    plat, writers = start_station_demo(
        out, seed, options["poses"], options["frames_per_pose"], settle
    )
    result = run_station_demo(plat, seed=seed, progress=progress,
                              store_for=lambda n: writers[n].store, **options)  # fmt: skip
    write_station_outputs(out, result, wall_s=time.monotonic() - wall0_s)
    return result


def clear_demo_dir(out: Path) -> None:
    """Make ``out`` ready for a demo: new, empty, or holding only an earlier demo's files."""
    for name in check_demo_dir(out):
        if name.endswith(".lock"):
            continue  # another command's lock: its own to remove (it may hold it now)
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()


def check_demo_dir(out: Path) -> set[str]:
    """What an earlier demo left in ``out`` (to be replaced); refuses anything else.

    Raises
    ------
    InputError
        ``out`` is a file, not writable, or holds files an earlier demo did not write.
    """
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory")
    check_writable(out, f"--out {out}")
    if not out.exists() or not any(out.iterdir()):
        return set()
    entries = {p.name for p in out.iterdir()}
    try:
        manifest = json.loads((out / "run.json").read_text(encoding="utf-8"))
        is_demo = manifest.get("provenance", {}).get("command") == "demo"
    except (OSError, ValueError, AttributeError):
        is_demo = False
    images = out / "images"
    own = re.compile(r"[A-Za-z0-9_-]+_\d{4}\.tiff")
    if images.is_dir() and any(not own.fullmatch(f.name) for f in images.iterdir()):
        is_demo = False
    foreign = sorted(entries - DEMO_FILES - LATER_FILES)
    if not is_demo or foreign:
        named = (
            f" ({', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''})" if foreign else ""
        )
        raise InputError(
            f"--out {out}: holds files that an earlier demo did not write{named}; "
            f"choose a new or empty directory"
        )
    return entries


def start_demo_run(
    out: Path,
    seed: int,
    poses: int,
    frames: int,
    preset: str = "thesis",
    device: str = "m1",
    plat: Any = None,
    settle: str = "vision",
) -> tuple[Any, RunWriter]:
    """The demo's platform and the writer of its run directory (run.json, commands.csv).

    The manifest records the design the demo draws (``random`` with the demo's design seed
    over the device's workspace, the thesis's for ``m1``), so ``make_design`` reproduces its
    commands. ``plat``: the platform, when the caller built it (a station demo's devices
    share one); built from ``preset`` and ``seed`` otherwise.
    """
    from ..experiments.demo import demo_design, demo_design_seed, device_workspace
    from ..kinematics.models import held_from_limits
    from ..sim import platform

    if plat is None:
        plat = platform(preset, seed=seed)  # an unknown preset fails before the folder is touched
    low, high = device_workspace(plat.manipulators[device].limits_um)
    clear_demo_dir(out)
    manifest = new_manifest(
        rig=SimRigSpec(preset=preset, seed=seed).to_dict(),
        target=plat.scene.board.spec,
        cameras=list(plat.cameras),
        design={
            "kind": "random",
            "poses": poses,
            "seed": demo_design_seed(seed),
            "low_um": low.tolist(),
            "high_um": high.tolist(),
        },
        settle=settle,
        frames_per_pose=frames,
        store="roi",
        command="demo",
        manipulator=device,
        held_joints_um=held_from_limits(plat.manipulators[device].limits_um),
        seed=seed,
    )
    return plat, RunDirectory.create(out, manifest, demo_design(seed, poses, (low, high)))


def start_station_demo(
    out: Path, seed: int, poses: int, frames: int, settle: str = "vision"
) -> tuple[Any, dict[str, Any]]:
    """The ``thesis-platform`` demo's platform and one run writer per device (``out/NAME``).

    ``out`` must be new, empty, or hold only an earlier station demo (its devices' run
    directories, calibration.json, cameras.json, results.json and report.html), which is
    replaced; everything is checked before anything is removed. ``settle`` is what each
    device's run.json records (``vision``, or ``fixed:SECONDS``).
    """
    from ..sim import platform

    plat = platform("thesis-platform", seed=seed)
    names = list(plat.manipulators)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory")
    files = ("calibration.json", "cameras.json", "results.json", "report.html")
    if out.is_dir():
        present = {p.name for p in out.iterdir()}
        others = sorted(present - set(names) - set(files))
        ours = not (present & set(files)) or _station_demo_results(out)
        if others or not ours:
            shown = ", ".join(others[:3] or sorted(present & set(files))[:3])
            raise InputError(
                f"--out {out}: holds files that an earlier station demo did not write "
                f"({shown}); choose a new or empty directory"
            )
        for name in names:  # all are checked before start_demo_run clears any of them
            check_demo_dir(out / name)
        for leftover in files:
            (out / leftover).unlink(missing_ok=True)
    writers = {
        name: start_demo_run(
            out / name, seed, poses, frames, "thesis-platform", name, plat, settle
        )[1]
        for name in names
    }
    return plat, writers


def _station_demo_results(out: Path) -> bool:
    """True when ``out`` holds a station demo's results.json."""
    try:
        data = json.loads((out / "results.json").read_text(encoding="utf-8"))
        return bool(data.get("provenance", {}).get("command") == "demo" and "devices" in data)
    except (OSError, ValueError, AttributeError):
        return False
