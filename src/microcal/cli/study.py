"""``microcal study``: the whole procedure on many seeded simulated platforms."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

from typer import Option

from ..report.console import output_console
from ._app import Tolerance, app

_Seeds = Annotated[int, Option(min=1, max=10000, help="Number of platforms (seeds).")]
_First = Annotated[int, Option(min=0, help="The first seed.")]
_Render = Annotated[bool, Option(help="Render and detect (full pipeline) instead of projecting.")]
_Workers = Annotated[int, Option(min=0, help="Processes at once (0: one per core).")]
_Poses = Annotated[int, Option(min=40, max=20000, help="Poses acquired per platform.")]
_Design = Annotated[
    str, Option(help="Command design: random, sobol, lhs, grid, chebyshev, adaptive.")
]
_Until = Annotated[
    float | None, Option(help="Adaptive design: stop at this predicted 95 % tip error, µm.")
]
_MaxPoses = Annotated[int, Option(min=20, max=20000, help="Adaptive design: at most this many.")]
_Closed = Annotated[bool, Option(help="Evaluate the closed loop (visual servoing) as well.")]
_Prior = Annotated[bool, Option(help="Add the Bayes estimator under each draw's own prior.")]


@app.command(short_help="The procedure on many simulated platforms.")
def study(
    out: Annotated[Path, Option("--out", "-o", help="Folder for study.json and study.html.")],
    preset: Annotated[str, Option(help="Simulated preset (population: each seed its own).")] = "",
    rig: Annotated[Path | None, Option(help="A simulated rig file: preset, settings.")] = None,
    seeds: _Seeds = 20, first_seed: _First = 0, render: _Render = False, workers: _Workers = 0,
    poses: _Poses = 170, design: _Design = "random", closed_loop: _Closed = False,
    tolerance_um: Tolerance = 0.5, prior: _Prior = False, until_um: _Until = None,
    max_poses: _MaxPoses = 400,
) -> None:  # fmt: skip
    """Calibrate, identify (matrix, quadratic, smooth, auto) and evaluate on N seeded platforms,
    each in its own process, against the oracle; write study.json and study.html.

    Example: microcal study --preset population --seeds 20 --out study-population
    (or --rig my-sim-rig.toml: a lab's own noise and travel, the seeds as given here;
    --design adaptive --until-um 1.0: the adaptive design, beside the random one grown)
    """
    from ..report.study_page import rig_time_lines, study_table
    from ..workflows.study import SeedRun, StudyConfig
    from ..workflows.study import study as run

    console = output_console()
    started = time.monotonic()

    def tick(done: int, total: int, run: SeedRun) -> None:
        spent = time.monotonic() - started
        left = f", about {spent / done * (total - done):.0f} s left" if done < total else ""
        console.print(f"seed {run.seed}: done ({done}/{total}, {run.wall_s:.1f} s{left})")

    config = StudyConfig(poses=poses, render=render, design=design, closed_loop=closed_loop,
                         tolerance_um=tolerance_um, prior=prior, until_um=until_um,
                         max_poses=max_poses)  # fmt: skip
    seed_range = range(first_seed, first_seed + seeds)
    path, result = run(out, preset, rig, seed_range, config, workers or None, tick)
    for name, med, p90 in study_table(result):
        console.print(f"{name:48s} median {med:9.3g}  p90 {p90:9.3g}")
    for line in rig_time_lines(result):
        console.print(line)
    console.print(f"Wrote {path} and study.html")
