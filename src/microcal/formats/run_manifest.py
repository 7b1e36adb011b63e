"""run.json's manifest, built in one place for ``acquire`` and the demo, and the demo's start."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

from ..devices.rig_spec import SimRigSpec
from ..errors import InputError
from .calibration_file import provenance
from .run_directory import RUN_FILE_NAMES, RunDirectory, RunWriter

__all__ = [
    "DEMO_FILES",
    "check_demo_dir",
    "clear_demo_dir",
    "new_manifest",
    "start_demo_run",
    "start_station_demo",
]

#: What a demo writes into its directory (and may replace on the next demo).
DEMO_FILES = frozenset(RUN_FILE_NAMES)


def new_manifest(
    *,
    rig: dict[str, Any],
    target: str,
    cameras: list[str],
    design: dict[str, object],
    settle: str,
    frames_per_pose: int,
    store: str,
    command: str,
    device: str = "",
    manipulator: str = "m1",
    held_joints_um: dict[str, float] | None = None,
    **provenance_extra: Any,
) -> dict[str, Any]:
    """The manifest of a new run: every option that shapes it, and where it came from.

    Parameters
    ----------
    rig : dict
        The rig as recorded (its spec; a resume must name the same).
    design : dict
        ``{"kind", "poses", "seed", "low_um", "high_um"}``: enough to draw the same commands
        again (``make_design(kind, poses, low_um, high_um, seed)``).
    settle : str
        ``vision`` or ``fixed:SECONDS``.
    store : str
        ``full`` frames or ``roi``.
    device : str
        The manipulator's identity (``Manipulator.identity``; left out when empty).
    manipulator : str
        The rig's device the run moves (left out when ``m1``, the only one of most rigs).
    held_joints_um : dict of str -> float, optional
        Joints the device holds still (an X-Y positioner's ``dz``) and their value; ``fit``
        leaves them out of the model (left out when none).
    """
    return (
        {
            "rig": rig,
            "target": target,
            "cameras": list(cameras),
            "design": design,
            "settle": settle,
            "frames_per_pose": frames_per_pose,
            "store": store,
            "provenance": provenance(command=command, **provenance_extra),
        }
        | ({"device": device} if device else {})
        | ({"manipulator": manipulator} if manipulator != "m1" else {})
        | ({"held_joints_um": dict(held_joints_um)} if held_joints_um else {})
    )


def clear_demo_dir(out: Path) -> None:
    """Make ``out`` ready for a demo: new, empty, or holding only an earlier demo's files."""
    for name in check_demo_dir(out):
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
    from .outputs import check_writable

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
    if not is_demo or not entries <= DEMO_FILES:
        raise InputError(
            f"--out {out}: holds files that an earlier demo did not write; "
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
    from ..kinematics.models import held_from_limits
    from ..procedures.demo import demo_design, demo_design_seed, device_workspace
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
