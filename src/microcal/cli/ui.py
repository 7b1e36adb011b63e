"""``microcal ui``: the station page, served to a browser."""

from __future__ import annotations

from typing import Annotated

from typer import Option

from ._app import app

_Host = Annotated[str, Option(help="Address to listen on; other than loopback needs the token.")]


@app.command(short_help="Serve the station page: live views, click to go, stop.")
def ui(
    calibration: Annotated[str, Option(help="calibration.json with the cameras.")],
    rig: Annotated[str, Option(help="'sim' or a rig file.")] = "sim",
    host: _Host = "127.0.0.1",
    port: Annotated[int, Option(min=0, max=65535, help="TCP port (0: any free one).")] = 8765,
    manipulator: Annotated[str | None, Option(help="Manipulator (if several).")] = None,
    seed: Annotated[int | None, Option(min=0, help="Seed of the simulated rig.")] = None,
    frames: Annotated[int, Option(min=1, help="Frames per camera of a measurement.")] = 5,
) -> None:  # fmt: skip
    """Serve the calibrated station to a browser until Ctrl-C: every camera live with the
    tip the calibration predicts, a click in two views gives a 3D target, go open or closed
    loop, stop. Listens on 127.0.0.1 unless --host says otherwise; then the printed address
    carries a token that every browser needs.

    Example: microcal ui --rig sim --calibration demo-out/calibration.json
    """
    from ..ui import serve_page

    say = lambda url: print(f"station page: {url}", flush=True)  # noqa: E731
    serve_page(rig, calibration, say, host=host, port=port, manipulator=manipulator, seed=seed,
               frames=frames)  # fmt: skip
    print("station page stopped")
