"""``microcal goto``: send the calibrated tip to a position in {G} and say where it arrived."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Literal

from typer import Argument, Option

from ._app import ObjectiveName, ScopeFile, Tolerance, app

_Rig = Annotated[str, Option(help="'sim' (the simulated thesis platform) or a rig file.")]
_Cal = Annotated[Path, Option(help="calibration.json with the cameras ('fit --cameras').")]
_Closed = Annotated[bool, Option(help="Close the loop: visual servoing to the tolerance.")]
_Along = Annotated[
    float | None,
    Option(help="Instead of X Y Z: move the tip this far along its approach axis, µm."),
]
_Coord = Annotated[
    float | None,
    Argument(help="Target in {G} ({M} with --scope), µm (x, then y, then z; -- before negatives)."),
]


@app.command(short_help="Move the tip to a position in {G}, open or closed loop.")
def goto(
    x: _Coord = None, y: _Coord = None, z: _Coord = None, *, calibration: _Cal,
    rig: _Rig = "sim", closed: _Closed = False, tolerance_um: Tolerance = 0.5,
    manipulator: Annotated[str | None, Option(help="Manipulator (if several).")] = None,
    seed: Annotated[int | None, Option(min=0, help="Seed of the simulated rig.")] = None,
    along_approach_um: _Along = None, scope: ScopeFile = None, objective: ObjectiveName = None,
) -> None:  # fmt: skip
    """Move the calibrated tip to (X, Y, Z) µm in {G} (a one-camera rig with --scope: in the
    microscope's frame {M}), or --along-approach-um D along the tool's approach axis, open
    loop or closed, and print where the cameras measured it.

    Example: microcal goto --calibration demo-out/calibration.json 3000 2000 1500 --closed
    """
    from ..report.text_tables import approach_line, arrival_line, correction_line, range_note
    from ..workflows.station import goto_target, open_station

    target = goto_target((x, y, z), along_approach_um)
    # One line per measurement of the closed loop, on standard error, as it is made.
    say = lambda step: print(correction_line(step), file=sys.stderr, flush=True)  # noqa: E731
    mode: Literal["open", "closed"] = "closed" if closed else "open"
    with open_station(rig, calibration, manipulator=manipulator, seed=seed, scope=scope,
                      objective=objective, on_correction=say) as station:  # fmt: skip
        if target is None:
            move, arrival = station.move_along_approach_um(float(along_approach_um or 0), mode,
                                                           tolerance_um)  # fmt: skip
            print(approach_line(move))
        else:
            arrival = station.move_to_um(target, mode, tolerance_um)
        outside = station.calibration.outside_joint_range_um(arrival.d_um)
    print(arrival_line(arrival, "{G}" if scope is None else "{M}"))
    if outside is not None:
        print(range_note(outside, "the joints it arrived at"), file=sys.stderr)
