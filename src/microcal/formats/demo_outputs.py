"""The files ``microcal demo`` writes beside its run: measurements, cameras, models, results.

The run itself (run.json, commands.csv, journal.jsonl, images/) is written while the demo
acquires (:class:`~microcal.formats.run_directory.RunWriter`); this writes what it derived.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..procedures.demo import DemoResult

__all__ = ["write_demo_outputs"]


def write_demo_outputs(out: Path, result: DemoResult, wall_s: float) -> None:
    """Write measurements.csv, cameras.json, calibration.json, results.json and report.html.

    Parameters
    ----------
    out : Path
        The demo's run directory.
    result : DemoResult
        What the demo measured and identified.
    wall_s : float
        Wall-clock seconds the demo took (``timing.wall_s`` of results.json).
    """
    from ..report import write_report
    from .calibration_file import (
        Calibration,
        ManipulatorCalibration,
        provenance,
        write_calibration,
    )
    from .cameras_file import cameras_to_dict, write_cameras
    from .measurements import write_measurements
    from .results_file import update_results

    out.mkdir(parents=True, exist_ok=True)
    ms = result.measurements
    write_measurements(
        out / "measurements.csv",
        result.d_um,
        np.array([m.p_um for m in ms]),
        std_um=np.array([m.std_um for m in ms]),
        status=[m.status for m in ms],
        reason=[m.reason for m in ms],
    )
    prov = provenance(command="demo", seed=result.seed)
    cameras = cameras_to_dict(result.calibration, prov)
    write_cameras(out / "cameras.json", cameras)
    poly, matrix = result.models["polynomial"], result.models["matrix"]
    extra = {"matrix_model": matrix.model.to_dict(), "matrix_validation": matrix.validation}
    entry = ManipulatorCalibration("m1", poly.model, poly.validation, extra)
    write_calibration(
        out / "calibration.json", Calibration({"m1": entry}, cameras["cameras"], prov)
    )
    results_path = out / "results.json"
    results_path.unlink(missing_ok=True)
    records = result.records
    update_results(results_path, {
        "stereo": {n: {"rms_px": c.rms_px} for n, c in result.calibration.cameras.items()},
        "measurement": {"rms_error_um": result.measurement_rms_um},
        "models": {k: {"validation": v.validation} for k, v in result.models.items()},
        "oracle": {f"{k}_um": v for k, v in result.oracle.items()},
        "acquisition": {
            "poses": len(records),
            "stored": sum(r["status"] == "ok" for r in records),
            "mean_settle_s": float(np.mean([r["settle_s"] for r in records])),
            "failed": [{"pose": r["pose"], "reason": r.get("reason", "")}
                       for r in records if r["status"] != "ok"],
        },
        **result.evaluation,
        "timing": {"simulated_s": result.sim_time_s, "wall_s": wall_s},
        "provenance": prov,
    })  # fmt: skip
    write_report(out)
