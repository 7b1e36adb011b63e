"""``microcal goto``: send the calibrated tip to a position in {G} and say where it arrived."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

from typer import Argument, Option

from ._app import Tolerance, app

_Rig = Annotated[str, Option(help="'sim' (the simulated thesis platform) or a rig file.")]
_Cal = Annotated[Path, Option(help="calibration.json with the cameras ('fit --cameras').")]
_Closed = Annotated[bool, Option(help="Close the loop: visual servoing to the tolerance.")]


@app.command(short_help="Move the tip to a position in {G}, open or closed loop.")
def goto(
    x: Annotated[float, Argument(help="Target x in {G}, µm.")],
    y: Annotated[float, Argument(help="Target y in {G}, µm.")],
    z: Annotated[float, Argument(help="Target z in {G}, µm.")],
    calibration: _Cal, rig: _Rig = "sim", closed: _Closed = False, tolerance_um: Tolerance = 0.5,
    manipulator: Annotated[str | None, Option(help="Manipulator (if several).")] = None,
    seed: Annotated[int | None, Option(min=0, help="Seed of the simulated rig.")] = None,
) -> None:  # fmt: skip
    """Move the calibrated tip to (X, Y, Z) µm in {G}, open loop or closed, and print where
    the cameras measured it, with its standard deviation.

    Example: microcal goto --calibration demo-out/calibration.json 3000 2000 1500 --closed
    """
    from ..report.text_tables import arrival_line, correction_line
    from ..workflows.station import open_station

    # One line per measurement of the closed loop, on standard error, as it is made.
    say = lambda step: print(correction_line(step), file=sys.stderr, flush=True)  # noqa: E731
    with open_station(rig, calibration, manipulator=manipulator, seed=seed,
                      on_correction=say) as station:  # fmt: skip
        arrival = station.move_to_um([x, y, z], "closed" if closed else "open", tolerance_um)
    print(arrival_line(arrival))
