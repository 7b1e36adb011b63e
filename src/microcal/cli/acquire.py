"""``microcal acquire``: drive the manipulator through a design and store its images."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from typer import Option

from ._app import app

_Out = Annotated[Path, Option("--out", "-o", help="Run directory to create (or resume).")]
_Rig = Annotated[str | None, Option(help="'sim' or a rig TOML file. [default: sim]")]
_Design = Annotated[str | None, Option(help="A design (above) or a CSV of dx_um,dy_um,dz_um.")]
_Poses = Annotated[int | None, Option(help="Poses of a generated design, 12 to 20000. [170]")]
_Seed = Annotated[int | None, Option(min=0, help="Seed of the design. [default: 0]")]
_Resume = Annotated[bool, Option(help="Continue a run that stopped (as it was begun).")]
_Settle = Annotated[str | None, Option(help="'vision' or 'fixed:SECONDS'. [default: vision]")]
_Frames = Annotated[int | None, Option(min=1, help="Frames per camera and pose. [default: 5]")]
_Store = Annotated[str | None, Option(help="'full' frames or 'roi' (around the target). [full]")]
_Manip = Annotated[str | None, Option(help="The rig's device to move (m1, m2, p1 ...). [m1]")]
_CheckCal = Annotated[str | None, Option(help="Check this calibration during this run.")]
_Every = Annotated[str | None, Option(help="Its check every N poses or Mmin minutes. [20]")]
_DryRun = Annotated[bool, Option("--dry-run", help="Check rig and design; nothing moves.")]
_Until = Annotated[float | None, Option(help="Adaptive: stop at this predicted 95 % error, µm.")]
_MaxPoses = Annotated[int | None, Option(min=20, help="Adaptive: at most this many poses. [400]")]
_Cameras = Annotated[str | None, Option(help="Adaptive: cameras.json it measures with.")]
_Scope = Annotated[Path | None, Option(help="One camera: scope.json (scope-calibrate).")]
_Objective = Annotated[str | None, Option(help="One camera: the scope file's set (40x).")]
_Volume = Annotated[str | None, Option(help="One camera: the volume's half sizes X,Y,Z µm.")]
_Approach = Annotated[float | None, Option(help="One camera: pipette's tilt, degrees. [30]")]
_Azimuth = Annotated[float | None, Option(help="One camera: its direction in x-y, deg. [0]")]


@app.command(short_help="Move through a design, settle and store images.")
def acquire(
    out: _Out, rig: _Rig = None, design: _Design = None, poses: _Poses = None,
    seed: _Seed = None, resume: _Resume = False, settle: _Settle = None, frames: _Frames = None,
    store: _Store = None, dry_run: _DryRun = False, manipulator: _Manip = None,
    check_calibration: _CheckCal = None, check_every: _Every = None, until_um: _Until = None,
    max_poses: _MaxPoses = None, cameras: _Cameras = None, scope: _Scope = None,
    objective: _Objective = None, volume_um: _Volume = None, approach_deg: _Approach = None,
    azimuth_deg: _Azimuth = None,
) -> None:  # fmt: skip
    """Drive the manipulator through a design and store images of every pose.

    Designs: random, sobol, lhs, grid (over the rig's soft limits); table-5-2, decoupling,
    iso-cube (evaluation trajectories); adaptive: batches chosen from what was measured
    until the predicted 95 % error of the compensated tip is below --until-um. One camera on a
    focus drive (--scope): the tip measured at each pose in the microscope's frame, poses
    filling --volume-um [100,100,25]. run.json records every option: a stopped run continues
    with `microcal acquire --out DIR --resume` alone.

    Example: microcal acquire --rig sim --design random --poses 170 --out runs/a
    (first: microcal acquire --rig myrig.toml --out runs/a --dry-run)
    """
    from ..workflows.acquire import AcquireRequest
    from ..workflows.adaptive_acquire import acquire_any

    request = AcquireRequest(out, rig, design, poses, seed, resume, settle, frames, store,
                             dry_run, manipulator, check_calibration, check_every, until_um,
                             max_poses, cameras, scope, objective, volume_um, approach_deg,
                             azimuth_deg)  # fmt: skip
    for line in acquire_any(request):
        print(line, flush=True)
