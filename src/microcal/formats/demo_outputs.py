"""The files ``microcal demo`` writes beside its run: measurements, cameras, models, results.

The run itself (run.json, commands.csv, journal.jsonl, images/) is written while the demo
acquires (:class:`~microcal.formats.run_directory.RunWriter`); this writes what it derived.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError

if TYPE_CHECKING:
    from ..procedures.demo import DemoResult
    from ..procedures.station_demo import StationDemoResult

__all__ = ["run_station_demo_files", "write_demo_outputs", "write_station_outputs"]


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
    from .calibration_file import Calibration, provenance, write_calibration
    from .cameras_file import cameras_to_dict, write_cameras
    from .results_file import update_results
    from .run_directory import RunDirectory

    out.mkdir(parents=True, exist_ok=True)
    poses = list(range(1, len(result.d_um) + 1))
    RunDirectory(out).write_measurements(poses, result.d_um, result.measurements)
    prov = provenance(command="demo", seed=result.seed)
    cameras = cameras_to_dict(result.calibration, prov)
    write_cameras(out / "cameras.json", cameras)
    if result.manipulator is None:
        raise InputError("demo: nothing was identified; no calibration to write")
    entry = result.manipulator
    write_calibration(
        out / "calibration.json", Calibration({entry.name: entry}, cameras["cameras"], prov)
    )
    results_path = out / "results.json"
    results_path.unlink(missing_ok=True)
    records = result.records
    axis_rms = result.measurement_rms_axis_um.tolist()
    update_results(results_path, {
        "stereo": {n: {"rms_px": c.rms_px, "model": c.model.kind}
                   for n, c in result.calibration.cameras.items()},
        "measurement": {"rms_error_um": result.measurement_rms_um,
                        "rms_error_axis_um": dict(zip("xyz", axis_rms, strict=True)),
                        "mahalanobis_mean_sq": result.mahalanobis_mean_sq},
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


def write_station_outputs(out: Path, result: StationDemoResult, wall_s: float) -> None:
    """Write a station demo's files: each device's as :func:`write_demo_outputs` does, in
    ``out/NAME``, and in ``out`` the station's calibration.json (every device, the cameras),
    cameras.json, results.json (``devices``: each device's results; ``meet``: the meet
    tests by mode) and report.html (the devices side by side, linking their reports)."""
    import json

    from .atomic import write_text_atomic
    from .calibration_file import Calibration, load_calibration, provenance, write_calibration
    from .results_file import update_results

    devices: dict[str, object] = {}
    entries = {}
    for name, device in result.devices.items():
        write_demo_outputs(out / name, device, wall_s)
        data = json.loads((out / name / "results.json").read_text(encoding="utf-8"))
        devices[name] = {k: v for k, v in data.items() if k not in ("format", "provenance")}
        entries[name] = load_calibration(out / name / "calibration.json").manipulators[name]
    first = next(iter(result.devices))
    cameras = load_calibration(out / first / "calibration.json").cameras
    prov = provenance(command="demo", seed=next(iter(result.devices.values())).seed,
                      preset="thesis-platform")  # fmt: skip
    write_calibration(out / "calibration.json", Calibration(entries, cameras, prov))
    write_text_atomic(
        out / "cameras.json", (out / first / "cameras.json").read_text(encoding="utf-8")
    )
    results_path = out / "results.json"
    results_path.unlink(missing_ok=True)
    update_results(results_path, {
        "devices": devices,
        "meet": {mode: m.as_dict() for mode, m in result.meet.items()},
        "timing": {"simulated_s": result.sim_time_s, "wall_s": wall_s},
        "provenance": prov,
    })  # fmt: skip
    from ..report import write_report

    write_report(out)


def run_station_demo_files(
    out: Path,
    seed: int,
    progress: Any,
    wall0_s: float,
    **options: Any,
) -> StationDemoResult:
    """``microcal demo --preset thesis-platform``: check ``out``, run the station demo with
    each device's run written as it goes, then write the station's files.

    ``options``: ``poses``, ``frames_per_pose`` and the rest of
    :func:`~microcal.procedures.station_demo.run_station_demo`'s keywords; ``wall0_s`` is
    when the command started (``time.monotonic``).
    """
    import time

    from ..procedures.station_demo import run_station_demo
    from .run_manifest import start_station_demo

    fixed = options.get("fixed_settle_s")
    settle = "vision" if fixed is None else f"fixed:{fixed:g}"
    plat, writers = start_station_demo(
        out, seed, options["poses"], options["frames_per_pose"], settle
    )
    result = run_station_demo(plat, seed=seed, progress=progress,
                              store_for=lambda n: writers[n].store, **options)  # fmt: skip
    write_station_outputs(out, result, wall_s=time.monotonic() - wall0_s)
    return result
