"""``microcal study``: the whole procedure on many seeded simulated platforms."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from rich.console import Console
from typer import Option

from ._app import app

_Seeds = Annotated[int, Option(min=1, max=10000, help="Number of platforms (seeds).")]
_First = Annotated[int, Option(min=0, help="The first seed.")]
_Render = Annotated[bool, Option(help="Render and detect (full pipeline) instead of projecting.")]
_Workers = Annotated[int, Option(min=0, help="Processes at once (0: one per core).")]


@app.command(short_help="Run the procedure on many simulated platforms; their distributions.")
def study(
    preset: Annotated[str, Option(help="Simulated platform preset (population draws each seed).")],
    out: Annotated[Path, Option("--out", "-o", help="Folder for study.json and study.html.")],
    seeds: _Seeds = 20, first_seed: _First = 0, render: _Render = False, workers: _Workers = 0,
) -> None:  # fmt: skip
    """Calibrate, identify (matrix, quadratic, auto) and evaluate on N seeded platforms,
    each in its own process, against the oracle; write study.json and study.html.

    Example: microcal study --preset population --seeds 20 --out study-population
    """
    from ..formats.study_file import check_study_folder, write_study
    from ..procedures.study import StudyConfig, run_study
    from ..report.study_page import study_page, study_table

    check_study_folder(out)
    console = Console()

    def tick(done: int, total: int, run: dict[str, object]) -> None:
        console.print(f"seed {run['seed']}: done ({done}/{total}, {run['wall_s']:.1f} s)")

    result = run_study(preset, range(first_seed, first_seed + seeds), StudyConfig(render=render),
                       workers or None, tick)  # fmt: skip
    path = write_study(out, result, study_page(result))
    for name, med, p90 in study_table(result):
        console.print(f"{name:48s} median {med:9.3g}  p90 {p90:9.3g}")
    console.print(f"Wrote {path} and study.html")
