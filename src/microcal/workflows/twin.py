"""``microcal twin``: serve the simulated platform through the real devices' protocols."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..formats.atomic import write_text_atomic
from ..formats.outputs import check_output, foreign_twin_rig
from ..formats.twin_rig_file import twin_rig_toml
from ..sim.twin import Twin

__all__ = ["TwinRequest", "serve_twin"]


@dataclass(frozen=True)
class TwinRequest:
    """What ``microcal twin`` is asked.

    Attributes
    ----------
    host : str
        The loopback address to listen on.
    port, frames_port : int
        The MCS2 peer's and the frame server's ports.
    time_scale : float
        Simulated seconds per wall-clock second.
    rig_out : Path, optional
        Where to write the twin's rig file (TOML).
    duration_s : float, optional
        Stop after this many seconds (until Ctrl-C without it).
    sample : str
        What lies on the patch rig's stage: ``tissue`` or ``slide`` (the calibration slide).
    """

    preset: str = "thesis"
    seed: int = 0
    host: str = "127.0.0.1"
    port: int = 55551
    frames_port: int = 55561
    time_scale: float = 1.0
    rig_out: Path | None = None
    duration_s: float | None = None
    sample: str = "tissue"


def serve_twin(request: TwinRequest, ready: Callable[[str], None]) -> str:
    """Start the twin, write its rig file if asked, serve until stopped; returns why it
    stopped. ``ready(line)`` is called once it listens, with one line saying where."""
    r = request
    if r.rig_out is not None:
        check_output(r.rig_out, kind="a twin rig file", foreign=foreign_twin_rig,
                     example="twin.toml", option="--rig-out")  # fmt: skip
    with Twin(r.preset, r.seed, host=r.host, mcs2_port=r.port, frames_port=r.frames_port,
              time_scale=r.time_scale, sample=r.sample) as served:  # fmt: skip
        if r.rig_out is not None:
            write_text_atomic(r.rig_out, twin_rig_toml(served.rig_description(), str(r.rig_out)))
        rig = f"rig file {r.rig_out}" if r.rig_out else "no rig file (--rig-out FILE writes one)"
        line = f"{served.describe()}; {rig}; Ctrl-C stops it"
        return served.serve(r.duration_s, ready=lambda: ready(line))
