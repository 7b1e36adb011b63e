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

__all__ = ["DEMO_FILES", "clear_demo_dir", "new_manifest", "start_demo_run"]

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
    """
    return {
        "rig": rig,
        "target": target,
        "cameras": list(cameras),
        "design": design,
        "settle": settle,
        "frames_per_pose": frames_per_pose,
        "store": store,
        "provenance": provenance(command=command, **provenance_extra),
    } | ({"device": device} if device else {})


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
    out: Path, seed: int, poses: int, frames: int, preset: str = "thesis"
) -> tuple[Any, RunWriter]:
    """The demo's platform and the writer of its run directory (run.json, commands.csv).

    The manifest records the design the demo draws (``random`` with the demo's design seed
    over the thesis's workspace), so ``make_design`` reproduces its commands.
    """
    from ..procedures.demo import demo_design, demo_design_seed
    from ..sim import platform
    from ..thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM

    plat = platform(preset, seed=seed)  # an unknown preset fails before the folder is touched
    clear_demo_dir(out)
    manifest = new_manifest(
        rig=SimRigSpec(preset=preset, seed=seed).to_dict(),
        target=plat.scene.board.spec,
        cameras=list(plat.cameras),
        design={
            "kind": "random",
            "poses": poses,
            "seed": demo_design_seed(seed),
            "low_um": WORKSPACE_MIN_UM.tolist(),
            "high_um": WORKSPACE_MAX_UM.tolist(),
        },
        settle="vision",
        frames_per_pose=frames,
        store="roi",
        command="demo",
        seed=seed,
    )
    return plat, RunDirectory.create(out, manifest, demo_design(seed, poses))
