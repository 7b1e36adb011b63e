"""``microcal acquire``: drive the manipulator through a design and store its images."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from typer import Option

from ..errors import InputError
from ._app import app

_Out = Annotated[Path, Option("--out", "-o", help="Run directory to create (or resume).")]
_Rig = Annotated[str, Option(help="'sim' or a rig TOML file.")]
_Design = Annotated[str, Option(help="A design (see above) or a CSV of dx_um,dy_um,dz_um.")]
_Poses = Annotated[int, Option(min=2, help="Poses of a generated design (the thesis: 170).")]
_Seed = Annotated[int, Option(min=0, help="Seed of the design.")]
_Resume = Annotated[bool, Option(help="Continue a run that stopped.")]
_Settle = Annotated[str, Option(help="'vision' or 'fixed:SECONDS' (the thesis: fixed:30).")]
_Frames = Annotated[int, Option(min=1, help="Frames stored per camera and pose.")]
_Store = Annotated[str, Option(help="'full' frames, or 'roi': only the region around the board.")]
_DryRun = Annotated[bool, Option("--dry-run", help="Check rig and design; nothing moves.")]


@app.command(short_help="Move through a design, settle and store images.")
def acquire(
    out: _Out, rig: _Rig = "sim", design: _Design = "random", poses: _Poses = 170,
    seed: _Seed = 0, resume: _Resume = False, settle: _Settle = "vision", frames: _Frames = 5,
    store: _Store = "full", dry_run: _DryRun = False,
) -> None:  # fmt: skip
    """Drive the manipulator through a design and store images of every pose.

    Designs: random, sobol, lhs, grid (over the rig's soft limits); table-5-2, decoupling,
    iso-cube (evaluation trajectories).

    Example: microcal acquire --rig sim --design random --poses 170 --out runs/a
    (first: microcal acquire --rig myrig.toml --out runs/a --dry-run)
    """
    from ..devices.rig import open_rig
    from ..formats.acquisition_run import acquire_remaining, check_out, open_run, plan_for
    from ..formats.options import parse_settle
    from ..formats.rig_file import load_rig
    from ..procedures.acquisition import AcquisitionConfig
    from ..procedures.dry_run import dry_run as check_rig

    if resume and dry_run:
        raise InputError("--dry-run and --resume: choose one")
    if store not in ("full", "roi"):
        raise InputError(f"--store: expected 'full' or 'roi', got {store!r}")
    mode, fixed_s = parse_settle(settle)
    check_out(out, resume, dry_run)
    spec = load_rig(rig)
    with open_rig(spec) as opened:
        m = opened.manipulator
        plan = None if resume else plan_for(design, poses, seed, m.limits_um, m.axes)
        if plan is not None and dry_run:
            print("\n".join(check_rig(m, opened.cameras, opened.board, plan, opened.description)))
            return
        writer, pose_ids, d = open_run(out, spec, opened, plan, settle, frames, store, resume)
        config = AcquisitionConfig(settle=mode, fixed_s=fixed_s, frames_per_pose=frames,
                                   store_roi=store == "roi")  # fmt: skip
        resume_hint = f"microcal acquire --rig {rig} --out {out} --resume"
        for line in acquire_remaining(opened, writer, pose_ids, d, config, resume_hint, resume):
            print(line)
