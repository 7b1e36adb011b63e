"""``microcal twin``: the simulated platform served through the real device protocols."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from typer import Option

from ._app import app

_Port = Annotated[int, Option(min=0, max=65535, help="The MCS2 peer's TCP port (0: any).")]
_Frames = Annotated[int, Option(min=0, max=65535, help="The frame server's TCP port (0: any).")]
_Scale = Annotated[float, Option(help="Simulated seconds per wall second (> 0).")]
_RigOut = Annotated[Path | None, Option(help="Write the twin's rig file here (TOML).")]
_Duration = Annotated[float | None, Option(min=0, help="Stop after this long, s (else Ctrl-C).")]


@app.command(short_help="Serve the simulator through the real device protocols.")
def twin(
    preset: Annotated[str, Option(help="The simulated platform's preset.")] = "thesis",
    seed: Annotated[int, Option(min=0, help="Seed of the simulated platform.")] = 0,
    host: Annotated[str, Option(help="The loopback address to listen on.")] = "127.0.0.1",
    port: _Port = 55551, frames_port: _Frames = 55561, time_scale: _Scale = 1.0,
    rig_out: _RigOut = None, duration_s: _Duration = None,
) -> None:  # fmt: skip
    """Serve the simulated platform as a rig: its manipulator and target stage as a SmarAct
    MCS2 controller, its cameras through a frame server that Micro-Manager reads, until
    Ctrl-C. Open it with the rig file it writes; the hardware drivers drive it.

    Example: microcal twin --seed 0 --rig-out twin.toml  (then, in another terminal:
    microcal acquire --rig twin.toml --out runs/a --dry-run)
    """
    from ..formats.atomic import write_text_atomic
    from ..formats.outputs import check_output, foreign_twin_rig
    from ..formats.twin_rig_file import twin_rig_toml
    from ..sim.twin import Twin

    if rig_out is not None:
        check_output(rig_out, kind="a twin rig file", foreign=foreign_twin_rig,
                     example="twin.toml", option="--rig-out")  # fmt: skip
    with Twin(preset, seed, host=host, mcs2_port=port, frames_port=frames_port,
              time_scale=time_scale) as served:  # fmt: skip
        if rig_out is not None:
            write_text_atomic(rig_out, twin_rig_toml(served.rig_description(), str(rig_out)))
        rig = f"rig file {rig_out}" if rig_out else "no rig file (--rig-out FILE writes one)"
        line = f"{served.describe()}; {rig}; Ctrl-C stops it"
        reason = served.serve(duration_s, ready=lambda: print(line, flush=True))
    print(f"digital twin stopped ({reason})")
