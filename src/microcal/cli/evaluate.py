"""``microcal evaluate``: ISO 9283 pose accuracy and the decoupling test on any rig."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

from typer import Option

from ..report.console import output_console, print_parts, staged_progress
from ._app import ObjectiveName, ScopeFile, Tolerance, app

PoseChoice = StrEnum("PoseChoice", {"table": "table-5-2", "cube": "iso-cube"})
TestChoice = StrEnum("TestChoice", {"pose_accuracy": "pose-accuracy", "decoupling": "decoupling",
                                    "distance": "distance", "stabilisation": "stabilisation",
                                    "all": "all"})  # fmt: skip
_Drift = Annotated[float, Option(min=0.0, help="Also the drift of AP over this many hours.")]
_Band = Annotated[float, Option(min=0.01, help="Stabilisation band, µm (ISO 9283 7.5).")]


_Calibration = Annotated[Path, Option(help="calibration.json (with cameras, see 'fit --cameras').")]
_Rig = Annotated[str, Option(help="'sim' (the simulated thesis platform) or a rig file.")]
_Test = Annotated[TestChoice, Option(help="Which test to run.")]
_Which = Annotated[str | None, Option(help="Manipulator name (optional if only one).")]
_Cycles = Annotated[int, Option(min=1, help="ISO 9283 cycles per pose (the standard: 30).")]
_Poses = Annotated[PoseChoice, Option(help="Test poses: Table 5-2, or ISO 9283's cube P1-P5.")]
_Frames = Annotated[int, Option(min=1, help="Frames measured per pose.")]
_Settle = Annotated[float, Option(min=0.0, help="Wait after the device reports it stopped, s.")]
_Seed = Annotated[int | None, Option(min=0, help="Seed of the simulated rig 'sim'.")]
_Out = Annotated[Path, Option("--out", "-o", help="results.json to write or update.")]
ControlChoice = StrEnum("ControlChoice", {"open": "open", "closed": "closed", "all": "all"})
_Control = Annotated[ControlChoice, Option(help="Open-loop conditions, the closed loop, or all.")]


@app.command(short_help="Pose accuracy (ISO 9283) and decoupling tests.")
def evaluate(
    calibration: _Calibration, rig: _Rig = "sim", test: _Test = TestChoice.all,
    manipulator: _Which = None, cycles: _Cycles = 3, poses: _Poses = PoseChoice.table,
    frames: _Frames = 5, settle_s: _Settle = 5.0, seed: _Seed = None,
    out: _Out = Path("results.json"), control: _Control = ControlChoice.open,
    tolerance_um: Tolerance = 0.5, drift_h: _Drift = 0.0, band_um: _Band = 2.0,
    scope: ScopeFile = None, objective: ObjectiveName = None,
) -> None:  # fmt: skip
    """Pose accuracy (ISO 9283) and decoupling tests without and with compensation.

    Each test runs uncalibrated, with the matrix compensator and with the optimal one, measured
    by the cameras (and on the simulator also by ground truth): ISO 9283's AP/RP, AD/RD and
    stabilisation time, the decoupling test, and with --drift-h the drift of AP. The rig is
    opened as 'microcal acquire' opens it: the simulator or a rig file's hardware.

    A one-camera rig (--scope scope.json): the tip by its image and a focus sweep, at ISO
    9283's cube in the calibration's working volume (--poses iso-cube).

    Example: microcal evaluate --rig sim --calibration calibration.json --control all
    """
    from ..report.text_tables import evaluation_tables, is_thesis_rig, unseen_lines
    from ..workflows.evaluate import EvaluateRequest
    from ..workflows.evaluate import evaluate as run

    request = EvaluateRequest(
        calibration, rig, test.value, manipulator, cycles, poses.value, frames, settle_s, seed,
        out, control.value, tolerance_um, drift_h, band_um, scope, objective,
    )  # fmt: skip
    with staged_progress() as progress:
        done = run(request, progress)
    thesis = is_thesis_rig(done.rig_record) and poses == PoseChoice.table
    tables = evaluation_tables(done.evaluation, poses.value, thesis=thesis)
    print_parts(
        output_console(), [*tables, *unseen_lines(done.evaluation.unseen), f"wrote {done.out}"]
    )
