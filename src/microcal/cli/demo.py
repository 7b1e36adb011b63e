"""``microcal demo``: the whole calibration on the simulated thesis platform."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

from rich.console import Console
from typer import Option

from ..report.console import output_console, print_parts, staged_progress
from ._app import app

QUICK_POSES, QUICK_FRAMES = 40, 2

_Seed = Annotated[int, Option(min=0, help="Seed of all random draws.")]
_Poses = Annotated[int, Option(min=20, max=20000, help="Poses to acquire (the thesis: 170).")]
_Quick = Annotated[bool, Option(help="A short run: 40 poses, 2 frames each, 1 ISO cycle.")]
_Out = Annotated[Path, Option("--out", "-o", help="Run directory (replaces an earlier demo).")]
_Preset = Annotated[
    str,
    Option(
        help="Simulated platform: thesis, telecentric, thesis-3cam, population, "
        "thesis-platform (two manipulators and a positioner), thesis-real (motion noise), "
        "thesis-tip (a glass pipette instead of the board), patch (one camera on a focus "
        "drive, a tilted pipette)."
    ),
]
_Model = Annotated[str, Option(help="Camera model: pinhole, affine or auto (by held-out error).")]


@app.command(short_help="Run the whole calibration on the simulated platform.")
def demo(
    seed: _Seed = 0, poses: _Poses = 170, quick: _Quick = False, out: _Out = Path("demo-out"),
    preset: _Preset = "thesis", camera_model: _Model = "auto",
) -> None:  # fmt: skip
    """Run the whole calibration on the simulated thesis platform and write its report.

    Stereo calibration from rendered images, acquisition with vision settling, 3D
    measurement, matrix and polynomial identification, compensation, ISO 9283 and decoupling
    tests; writes the run directory, cameras.json, calibration.json, results.json and
    report.html, and compares the figures with the thesis's.

    --preset thesis-platform: each device (m1, m2, positioner p1) in the one camera frame,
    each in its own directory under --out, then the meet test of the two tips.

    Example: microcal demo --seed 3 --out demo-3 (or --preset telecentric)
    """
    from ..report.text_tables import demo_closing, demo_intro, demo_summary
    from ..workflows.demo import DemoRequest
    from ..workflows.demo import demo as run
    from ..workflows.options import check_camera_model

    wall0, console = time.monotonic(), output_console()
    n_poses, frames = (QUICK_POSES, QUICK_FRAMES) if quick else (poses, 5)
    check_camera_model(camera_model)
    if preset == "thesis-platform":
        return _station(out, seed, n_poses, frames, quick, camera_model, console, wall0)
    if preset == "patch":
        return _patch(out, seed, 80 if poses == 170 and not quick else n_poses, quick, console)
    request = DemoRequest(out, seed, n_poses, frames, quick, preset, camera_model)
    with staged_progress(console) as progress:
        result = run(request, progress, lambda: console.print(demo_intro(out, n_poses)), wall0)
    print_parts(console, demo_summary(result, frames))
    print_parts(console, demo_closing(result, out, time.monotonic() - wall0))


def _station(out: Path, seed: int, poses: int, frames: int, quick: bool, camera_model: str,
             console: Console, wall0: float) -> None:  # fmt: skip
    from ..report.text_tables import station_summary
    from ..workflows.demo import run_station_demo_files

    console.print(f"microcal demo on the simulated thesis-platform (every device in one camera "
                  f"frame, then the meet test), writing {out}/")  # fmt: skip
    with staged_progress(console) as progress:
        result = run_station_demo_files(
            out, seed, progress, wall0, poses=poses, frames_per_pose=frames,
            frames_per_view=4 if quick else 8, cycles=1 if quick else 3,
            decoupling_samples=5 if quick else 17, camera_model=camera_model,
            meet_cycles=1 if quick else 2,
        )  # fmt: skip
    names = ", ".join(f"{n}/" for n in result.devices)
    print_parts(console, [*station_summary(result), f"wrote {out}/: {names} (each a demo run "
                          "with its report), calibration.json (every device), cameras.json, results"
                          f".json, report.html ({time.monotonic() - wall0:.0f} s)"])  # fmt: skip


def _patch(out: Path, seed: int, poses: int, quick: bool, console: Console) -> None:
    from ..report.patch_lines import patch_demo_lines
    from ..workflows.patch_demo import patch_demo

    intro = (f"microcal demo on the simulated one-camera patch rig ({poses} poses, focus "
             f"sweeps), writing {out}/")  # fmt: skip
    with staged_progress(console) as progress:
        run = patch_demo(out, seed, poses, quick, progress, lambda: console.print(intro))
    print_parts(
        console,
        [
            *patch_demo_lines(run.result),
            f"wrote {out}/: journal.jsonl, "
            f"scope.json, calibration.json, results.json, report.html ({run.wall_s:.0f} s)",
        ],
    )
