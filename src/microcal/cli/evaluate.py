"""``microcal evaluate``: ISO 9283 pose accuracy and the decoupling test on any rig."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

from rich.console import Console
from typer import Option

from ..report.console import print_parts, staged_progress
from ._app import Tolerance, app

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
) -> None:  # fmt: skip
    """Pose accuracy (ISO 9283) and decoupling tests without and with compensation.

    Each test runs uncalibrated, with the matrix compensator and with the optimal one, measured
    by the cameras (and on the simulator also by ground truth): ISO 9283's AP/RP, AD/RD and
    stabilisation time, the decoupling test, and with --drift-h the drift of AP. The rig is
    opened as 'microcal acquire' opens it: the simulator or a rig file's hardware.

    Example: microcal evaluate --rig sim --calibration calibration.json --control all
    """
    from ..devices.rig import open_rig
    from ..formats import calibration_file, calibration_update, json_file, options, results_file
    from ..formats.rig_file import load_rig
    from ..procedures.evaluation import run_evaluation
    from ..report.text_tables import evaluation_tables, is_thesis_rig

    json_file.check_json_output(out, results_file.RESULTS_FORMAT, "results.json")
    cal = calibration_file.load_calibration(calibration)
    m, models = cal.manipulator(manipulator), calibration_update.camera_models(cal)
    spec = options.rig_with_seed(load_rig(rig), seed)
    with open_rig(spec) as rig_, staged_progress() as progress:
        opened = rig_.for_calibration(m.name)
        parts = run_evaluation(
            opened.manipulator, opened.clock, opened.cameras, models, opened.board, m,
            tests=test.value, poses=poses.value, cycles=cycles, frames=frames, settle_s=settle_s,
            truth=opened.truth, sensors=opened.sensors, progress=progress,
            control=control.value, tolerance_um=tolerance_um, drift_s=drift_h * 3600.0,
            band_um=band_um,
        )  # fmt: skip
    results_file.update_results(out, parts)
    thesis = is_thesis_rig(spec.to_dict()) and poses == PoseChoice.table
    print_parts(Console(), [*evaluation_tables(parts, poses.value, thesis=thesis), f"wrote {out}"])
