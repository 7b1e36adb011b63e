"""``microcal scope-calibrate`` and ``scope-show``: a microscope camera against its X-Y stage."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from typer import Option

from ._app import app

_Rig = Annotated[str, Option(help="'sim' (the simulated microscope) or a rig file with "
                                  "a [microscope] (X-Y stage and focus).")]  # fmt: skip
_Objective = Annotated[str, Option(help="The objective's name: its set in the file (40x).")]
_File = Annotated[Path, Option(help="The scope file (one set per objective).")]


@app.command("scope-calibrate", short_help="Calibrate a microscope camera against its stage.")
def scope_calibrate(
    objective: _Objective, out: _File = Path("scope.json"), rig: _Rig = "sim",
    target: Annotated[str | None, Option(help="The slide (dotgrid:...:markers=...).")] = None,
    um_per_px: Annotated[float | None, Option(min=0, help="Nominal pixel size, µm.")] = None,
    na: Annotated[float | None, Option(min=0, help="The objective's NA.")] = None,
    camera: Annotated[str | None, Option(help="The camera (a rig of several).")] = None,
    seed: Annotated[int, Option(min=0, help="Seed of the simulated microscope.")] = 0,
    field_curvature: Annotated[bool, Option(help="Also fit the focal surface.")] = False,
) -> None:  # fmt: skip
    """Move a slide by known steps with the X-Y stage and the focus, and fit the camera's
    image-to-stage affine (Micro-Manager's pixel-size affine), pixel size, distortion and
    focus-axis angle; add the set of OBJECTIVE to the scope file (other sets stay).

    Example: microcal scope-calibrate --rig sim --objective 40x --out scope.json
    """
    from ..report.scope_lines import scope_lines
    from ..workflows.scope import ScopeRequest
    from ..workflows.scope import scope_calibrate as work

    req = ScopeRequest(rig, objective, out, target, um_per_px, na, camera, seed,
                       field_curvature=field_curvature)  # fmt: skip
    result = work(req)
    for line in scope_lines(objective, result.record):
        print(line)
    print(f"{result.path}: objectives {', '.join(result.objectives)}")


@app.command("scope-show", short_help="Show one objective's set of a scope file.")
def scope_show(objective: _Objective, scope: _File = Path("scope.json")) -> None:
    """Print OBJECTIVE's calibration from the scope file, with the six numbers of
    Micro-Manager's setPixelSizeAffine.

    Example: microcal scope-show --scope scope.json --objective 40x
    """
    from ..report.scope_lines import scope_lines
    from ..workflows.scope import scope_show as work

    for line in scope_lines(objective, work(scope, objective)):
        print(line)
