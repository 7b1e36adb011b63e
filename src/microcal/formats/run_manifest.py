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
    )


def clear_demo_dir(out: Path) -> None:
    """Make ``out`` ready for a demo: new, empty, or holding only an earlier demo's files."""
    from .outputs import check_writable

    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory")
    check_writable(out, f"--out {out}")
    if not out.exists() or not any(out.iterdir()):
        return
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
    for name in entries:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()


def start_demo_run(
    out: Path,
    seed: int,
    poses: int,
    frames: int,
    preset: str = "thesis",
    device: str = "m1",
    plat: Any = None,
) -> tuple[Any, RunWriter]:
    """The demo's platform and the writer of its run directory (run.json, commands.csv).

    The manifest records the design the demo draws (``random`` with the demo's design seed
    over the device's workspace, the thesis's for ``m1``), so ``make_design`` reproduces its
    commands. ``plat``: the platform, when the caller built it (a station demo's devices
    share one); built from ``preset`` and ``seed`` otherwise.
    """
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
        settle="vision",
        frames_per_pose=frames,
        store="roi",
        command="demo",
        manipulator=device,
        seed=seed,
    )
    return plat, RunDirectory.create(out, manifest, demo_design(seed, poses, (low, high)))


def start_station_demo(out: Path, seed: int, poses: int, frames: int) -> tuple[Any, dict[str, Any]]:
    """The ``thesis-platform`` demo's platform and one run writer per device (``out/NAME``).

    ``out`` must be new, empty, or hold only an earlier station demo (its devices' run
    directories, calibration.json, cameras.json, results.json and report.html), which is
    replaced.
    """
    from ..sim import platform

    plat = platform("thesis-platform", seed=seed)
    names = list(plat.manipulators)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; choose a directory")
    if out.is_dir():
        files = ("calibration.json", "cameras.json", "results.json", "report.html")
        own = set(names) | set(files)
        others = sorted(p.name for p in out.iterdir() if p.name not in own)
        if others or not _station_demo_or_empty(out):
            raise InputError(
                f"--out {out}: holds files that an earlier station demo did not write "
                f"({', '.join(others[:3]) or 'results.json'}); choose a new or empty directory"
            )
        for name in names:  # each device's directory must be an earlier demo's
            if (out / name).exists():
                clear_demo_dir(out / name)
        for leftover in files:
            (out / leftover).unlink(missing_ok=True)
    writers = {
        name: start_demo_run(out / name, seed, poses, frames, "thesis-platform", name, plat)[1]
        for name in names
    }
    return plat, writers


def _station_demo_or_empty(out: Path) -> bool:
    """True when ``out``'s results.json (if any) is a station demo's."""
    results = out / "results.json"
    if not results.exists():
        return True
    try:
        data = json.loads(results.read_text(encoding="utf-8"))
        return bool(data.get("provenance", {}).get("command") == "demo" and "devices" in data)
    except (OSError, ValueError, AttributeError):
        return False
