"""``microcal tool-centre`` and ``microcal find-tip``: the tool that does the work."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from typer import Option

from ..report.console import staged_progress
from ._app import app

_Rig = Annotated[str, Option(help="'sim' or a rig file.")]
_Seed = Annotated[int | None, Option(min=0, help="Seed of the simulated rig.")]
_Man = Annotated[str | None, Option(help="Manipulator (if several).")]


@app.command("tool-centre", short_help="Measure a tool's tip in its board's frame.")
def tool_centre(
    calibration: Annotated[Path, Option(help="calibration.json of the board, with cameras.")],
    tip: Annotated[str, Option(help="The tool's tip spec, e.g. tip:jaw:30:40.")],
    out: Annotated[Path, Option("--out", "-o", help="The calibration with the tool to write.")],
    rig: _Rig = "sim", manipulator: _Man = None, seed: _Seed = None,
    frames: Annotated[int, Option(min=1, max=100, help=(
        "Frames per camera and pose: 30 put a jaw's tip within 0.5 µm on 22 µm pixels on 9 "
        "of 10 simulated fits (each frame's edges fit costs about 0.2 s per camera); 2 for "
        "a quick look (a few µm)."))] = 30,
    settle_s: Annotated[float, Option(min=0.0, help="Wait after each move, s.")] = 2.0,
) -> None:  # fmt: skip
    """Measure the board and the tool's tip at the calibration's ten check poses, fit the
    tip's offset in the board's frame with its covariance, and write the calibration with it
    (its tool_centre) to a new file. A changed tool (a new pipette) needs only this again.

    Example: microcal tool-centre --rig myrig.toml --calibration runs/a/calibration.json
    --tip tip:jaw:30:40 --out runs/a/calibration-jaw.json
    """
    from ..report.tool_lines import tool_centre_lines
    from ..workflows.tool_centre import measure_tool_centre

    with staged_progress() as progress:
        tick = lambda done, total: progress("poses measured", done, total)  # noqa: E731
        done = measure_tool_centre(rig, calibration, out, tip, manipulator=manipulator,
                                   seed=seed, frames=frames, settle_s=settle_s,
                                   progress=tick)  # fmt: skip
    for line in tool_centre_lines(done.tool, done.poses):
        print(line)
    print(f"wrote {done.out}")


@app.command("find-tip", short_help="Find a new tool's tip and centre it in a camera.")
def find_tip(
    rig: _Rig = "sim", manipulator: _Man = None, seed: _Seed = None,
    camera: Annotated[str | None, Option(help="The camera to centre it in (the first).")] = None,
    tip: Annotated[str, Option(help="The tool's tip spec.")] = "tip",
    reach_um: Annotated[float, Option(min=0.0, help="How far the search goes, µm.")] = 2000.0,
) -> None:  # fmt: skip
    """Jog an axis back and forth, find what moved in the images, home in on the tool's tip
    and centre it in the camera, then print where it is (joints, and the tip in each camera).
    A tool that is not found is left where it began (one error line). No focus drive is
    moved: the tip is centred, not focused (one camera on a focus drive: acquire --scope).

    Example: microcal find-tip --rig myrig.toml --tip tip:needle
    """
    from ..errors import DetectionError
    from ..report.tool_lines import tip_search_lines
    from ..workflows.find_tip import find_tool_tip

    done = find_tool_tip(rig, manipulator=manipulator, seed=seed, camera=camera, tip=tip,
                         reach_um=reach_um)  # fmt: skip
    lines = tip_search_lines(done.search, done.camera, done.seen_px)
    if not done.search.found:
        raise DetectionError(f"find-tip: {lines[0]}")
    for line in lines:
        print(line)
