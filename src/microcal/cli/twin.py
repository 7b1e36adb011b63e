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
_Sample = Annotated[str, Option(help="What lies on the patch rig's stage: tissue or slide.")]
_Duration = Annotated[float | None, Option(min=0, help="Stop after this long, s (else Ctrl-C).")]


@app.command(short_help="Serve the simulator through the real device protocols.")
def twin(
    preset: Annotated[str, Option(help="The preset (patch: the one-camera scope).")] = "thesis",
    seed: Annotated[int, Option(min=0, help="Seed of the simulated platform.")] = 0,
    host: Annotated[str, Option(help="The loopback address to listen on.")] = "127.0.0.1",
    port: _Port = 55551, frames_port: _Frames = 55561, time_scale: _Scale = 1.0,
    rig_out: _RigOut = None, duration_s: _Duration = None, sample: _Sample = "tissue",
) -> None:  # fmt: skip
    """Serve the simulated platform as a rig: its manipulator and target stage as a SmarAct
    MCS2 controller, its cameras through a frame server that Micro-Manager reads, until
    Ctrl-C. Open it with the rig file it writes; the hardware drivers drive it.

    Example: microcal twin --seed 0 --rig-out twin.toml  (then, in another terminal:
    microcal acquire --rig twin.toml --out runs/a --dry-run). With --preset patch --sample
    slide the calibration slide lies on the stage (for microcal scope-calibrate).
    """
    from ..workflows.twin import TwinRequest, serve_twin

    request = TwinRequest(preset, seed, host, port, frames_port, time_scale, rig_out, duration_s,
                          sample)  # fmt: skip
    reason = serve_twin(request, ready=lambda line: print(line, flush=True))
    print(f"digital twin stopped ({reason})")
