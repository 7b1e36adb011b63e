"""``goto`` (open and closed loop), ``check`` and ``evaluate`` with a tool's tip as the target,
on the simulated ``thesis-tip`` platform: the figures of docs/vision.md.

Run from the repository root (minutes: every measurement detects the tip in each camera's
frames; under the shared lock):

    .venv/bin/python scripts/tip_commands_figures.py --spec tip:needle:20:5 --seed 0

The rig is a rig file ``driver = "sim"``, ``preset = "thesis-tip"`` with ``[overrides] board
= SPEC``; the calibration is the simulator's truth (its cameras and its manipulator's static
model), so what the figures show is the tip's measurement through each command, not a
calibration's error. Each command runs through its workflow as the command line runs it
(``open_station`` for ``goto``, ``check_calibration``, ``evaluate``), with ``--frames``
frames per camera and measurement. The closed loop servoes to ``--tolerance-um`` with
``--frames`` to ``--frames-max`` frames and at most ``--iterations`` corrections. Prints a
Markdown table per command, then one JSON line of everything.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from microcal import sim
from microcal.control.visual_servo import ServoConfig
from microcal.errors import MicrocalError
from microcal.formats.calibration_file import Calibration, write_calibration
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
from microcal.procedures.check import CheckConfig
from microcal.workflows.check import check_calibration
from microcal.workflows.evaluate import EvaluateRequest, evaluate
from microcal.workflows.station import open_station

#: goto's targets in {G}, µm (in the thesis-tip cameras' view).
TARGETS_UM = ((3000.0, 2000.0, 1500.0), (5000.0, 4000.0, 2000.0), (2000.0, 5000.0, 1000.0),
              (6000.0, 3000.0, 2500.0), (4000.0, 6000.0, 1800.0))  # fmt: skip
NO_VALIDATION = {"n_fit": 0, "n_validate": 0, "mean_um": 0.0, "std_um": 0.0, "max_um": 0.0,
                 "rms_um": 0.0}  # fmt: skip


def truth_calibration(path: Path, seed: int, spec: str) -> Path:
    """calibration.json of the simulator's true cameras and static model."""
    plat = sim.platform("thesis-tip", seed=seed, overrides={"board": spec})
    cams = {n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(),
                "dist": m.dist.tolist(), "R": m.R.tolist(), "t_um": m.t_um.tolist()}
            for n, m in plat.camera_models.items()}  # fmt: skip
    entries = {name: ManipulatorCalibration(name, m.truth.static, NO_VALIDATION)
               for name, m in plat.manipulators.items()}  # fmt: skip
    return write_calibration(path, Calibration(entries, cams, {}))


def goto_figures(rig: Path, cal: Path, args: argparse.Namespace) -> list[dict[str, object]]:
    """Each target open loop, then closed loop: error by truth and as measured."""
    servo = ServoConfig(tolerance_um=args.tolerance_um, frames_min=args.frames,
                        frames_max=args.frames_max, max_iterations=args.iterations)  # fmt: skip
    rows: list[dict[str, object]] = []
    with open_station(str(rig), str(cal), frames=args.frames, servo=servo) as station:
        truth = station.rig.truth
        assert truth is not None  # the simulator
        for target in TARGETS_UM:
            for mode in ("open", "closed"):
                t0 = time.perf_counter()
                try:
                    a = station.move_to_um(target, mode)
                except MicrocalError as exc:
                    rows.append({"target_um": target, "mode": mode, "error": str(exc)})
                    continue
                e_true = truth() - np.asarray(target)
                rows.append({
                    "target_um": target, "mode": mode, "status": a.status,
                    "iterations": a.iterations, "frames": a.frames,
                    "measured_error_um": round(float(np.linalg.norm(a.error_um)), 3),
                    "true_error_um": round(float(np.linalg.norm(e_true)), 3),
                    "true_error_xyz_um": [round(float(v), 2) for v in e_true],
                    "std_um": [round(float(v), 2) for v in a.std_um],
                    "s": round(time.perf_counter() - t0, 1),
                })  # fmt: skip
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--spec", default="tip:needle:20:5")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--frames-max", type=int, default=8)
    parser.add_argument("--iterations", type=int, default=4)
    parser.add_argument("--tolerance-um", type=float, default=0.5)
    parser.add_argument("--check-frames", type=int, default=2)
    parser.add_argument("--commands", nargs="+", default=["goto", "check", "evaluate"])
    args = parser.parse_args()
    out: dict[str, object] = {"spec": args.spec, "seed": args.seed, "frames": args.frames}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        rig = d / "rig.toml"
        rig.write_text(f'driver = "sim"\npreset = "thesis-tip"\nseed = {args.seed}\n'
                       f'[overrides]\nboard = "{args.spec}"\n')  # fmt: skip
        cal = truth_calibration(d / "calibration.json", args.seed, args.spec)
        if "goto" in args.commands:
            rows = goto_figures(rig, cal, args)
            out["goto"] = rows
            print(f"goto, {args.spec}, seed {args.seed}, {args.frames} frames per camera; closed "
                  f"loop to {args.tolerance_um} µm, {args.frames}-{args.frames_max} frames, "
                  f"at most {args.iterations} corrections")  # fmt: skip
            print(
                "| target (µm) | loop | ended | corrections | error as measured (µm) "
                "| error by truth (µm) | by truth x, y, z (µm) | std x, y, z (µm) | s |"
            )
            print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
            for r in rows:
                if "error" in r:
                    print(f"| {r['target_um']} | {r['mode']} | refused: {r['error']} |||||||")
                    continue
                print(f"| {r['target_um']} | {r['mode']} | {r['status']} | {r['iterations']} "
                      f"| {r['measured_error_um']} | {r['true_error_um']} "
                      f"| {r['true_error_xyz_um']} | {r['std_um']} | {r['s']} |")  # fmt: skip
        if "check" in args.commands:
            t0 = time.perf_counter()
            cfg = CheckConfig(frames=args.check_frames, settle_s=1.0)
            done = check_calibration(str(rig), str(cal), d / "check.json", config=cfg)
            saved = json.loads((d / "check.json").read_text())
            res = done.result
            out["check"] = {"verdict": res.verdict, "target": saved.get("target"),
                            "offset_um": [round(float(v), 2) for v in res.offset_um],
                            "offset_std_um": [round(float(v), 2) for v in res.offset_std_um],
                            "p_value": res.p_value, "offset_p_value": res.offset_p_value,
                            "s": round(time.perf_counter() - t0, 1)}  # fmt: skip
            print(f"check ({args.check_frames} frames): {out['check']}")
        if "evaluate" in args.commands:
            t0 = time.perf_counter()
            req = EvaluateRequest(cal, str(rig), "pose-accuracy", poses="iso-cube", cycles=1,
                                  frames=args.frames, settle_s=1.0,
                                  out=d / "results.json")  # fmt: skip
            evaluate(req)
            saved = json.loads((d / "results.json").read_text())
            ap = {src: {cond: [f["mean_ap_p_um"], f["max_ap_p_um"]] for cond, f in by.items()}
                  for src, by in saved["pose_accuracy"].items()}  # fmt: skip
            out["evaluate"] = {"target": saved.get("target"), "ap_p_mean_max_um": ap,
                               "s": round(time.perf_counter() - t0, 1)}  # fmt: skip
            print(f"evaluate (iso-cube, 1 cycle, {args.frames} frames): {out['evaluate']}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
