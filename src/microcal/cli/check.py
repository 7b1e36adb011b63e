"""``microcal check``: is a calibration still valid? (and a quick update of its offset)"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from typer import Option

from ..report.console import staged_progress
from ._app import ObjectiveName, ScopeFile, app

_Cal = Annotated[Path, Option(help="calibration.json with the cameras ('fit --cameras').")]
_Out = Annotated[Path, Option("--out", "-o", help="check.json to write.")]
_Frames = Annotated[int, Option(min=1, max=1000, help="Frames per camera and check pose.")]
_Alpha = Annotated[float, Option(min=0.001, max=0.2, help="False-alarm rate of each test.")]
_Sigma = Annotated[float, Option(min=1.0, help="Flag an offset this far from the history's.")]
_Update = Annotated[Path | None, Option(help="When only the offset moved: write the updated "
                                             "calibration here and check it again.")]  # fmt: skip


@app.command(short_help="Check a calibration on its rig (and update its offset).")
def check(
    calibration: _Cal, rig: Annotated[str, Option(help="'sim' or a rig file.")] = "sim",
    out: _Out = Path("check.json"), frames: _Frames = 20,
    settle_s: Annotated[float, Option(min=0.0, help="Wait after each move, s.")] = 5.0,
    alpha: _Alpha = 0.05, history_sigma: _Sigma = 3.0, update: _Update = None,
    manipulator: Annotated[str | None, Option(help="Manipulator (if several).")] = None,
    seed: Annotated[int | None, Option(min=0, help="Seed of the simulated rig.")] = None,
    scope: ScopeFile = None, objective: ObjectiveName = None,
) -> None:  # fmt: skip
    """Re-measure ten poses of the ISO cube and test them against the calibration: still
    valid, the offset moved by (x, y, z) ± (a re-mounted device, an exchanged tool), or the
    model no longer fits (calibrate again). The checks of a calibration are kept beside it
    (CALIBRATION.checks.jsonl); the first valid one is the reference of the later ones.

    Example: microcal check --rig myrig.toml --calibration runs/a/calibration.json
    --out runs/a/check.json --update runs/a/calibration-moved.json
    """
    from ..report.text_tables import check_lines
    from ..workflows.check import CheckConfig, check_calibration

    cfg = CheckConfig(frames=frames, settle_s=settle_s, alpha=alpha)
    with staged_progress() as progress:
        tick = lambda done, total: progress("check poses measured", done, total)  # noqa: E731
        done = check_calibration(rig, calibration, out, manipulator=manipulator, seed=seed,
                                 config=cfg, history_sigma=history_sigma, update=update,
                                 progress=tick, scope=scope, objective=objective)  # fmt: skip
    for line in check_lines(done.result, done.flag, done.update, done.replayed):
        print(line)
    print(f"wrote {out}")
