"""Does ``microcal check --update`` restore the open-loop accuracy after a device moved?

For each seed: the thesis platform with its end-effector shifted by OFFSET µm in a random
direction (a re-mounted device). Absolute open-loop accuracy by ground truth (the optimal
compensator sent to positions in {G}: the Table 5-2 poses from the original calibration's
base, 3 cycles; AP_P per pose, mean) with (a) the original calibration (stale), (b) that
calibration after ``check --update`` (ten check poses, rendered frames), (c) a fresh
calibration of the moved platform (170 poses). Simulated time of the check and update.

    python scripts/check_update_figures.py demo-out/calibration.json --seeds 3 --offset 30
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from microcal.control.feedforward import FeedForward, extra_inputs_reader
from microcal.experiments.demo import run_demo
from microcal.formats.calibration_file import load_calibration
from microcal.metrics import pose_statistics
from microcal.sim import platform
from microcal.thesis.experiment import TABLE_5_2_POSES_UM
from microcal.workflows.check import check_calibration


def absolute_ap_um(model, seed: int, overrides: dict) -> float:
    plat = platform("thesis", seed=seed, overrides=overrides)
    ff = FeedForward(plat.manipulator, model, "optimal", extra_inputs_reader(model, {}), plat.clock)
    aps = []
    for pose in TABLE_5_2_POSES_UM:
        target = BASE + pose
        got = []
        for _ in range(3):
            ff.move_to_position_um(target)
            plat.manipulator.wait_until_stopped(plat.clock)
            plat.clock.sleep(5.0)
            got.append(plat.truth_position_um())
        aps.append(pose_statistics(target, np.array(got)).ap_p_um)
    return float(np.mean(aps))


def main() -> None:
    global BASE
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("calibration")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=300)
    ap.add_argument("--offset", type=float, default=30.0)
    args = ap.parse_args()
    cal = load_calibration(args.calibration)
    model = cal.manipulator().model
    BASE = model.p_base_um
    rows = []
    for k in range(args.seeds):
        seed = args.first_seed + k
        v = np.random.default_rng(seed).normal(size=3)
        shift = (v / np.linalg.norm(v) * args.offset).round(3).tolist()
        over = {"manipulator.mount_offset_um": shift}
        with tempfile.TemporaryDirectory() as tmp:
            rig = Path(tmp) / "moved.toml"
            rig.write_text(f'driver = "sim"\nseed = {seed}\n[overrides.manipulator]\n'
                           f"mount_offset_um = {shift}\n")  # fmt: skip
            copy = Path(tmp) / "calibration.json"  # its check history stays in tmp
            copy.write_bytes(Path(args.calibration).read_bytes())
            done = check_calibration(rig, copy, Path(tmp) / "check.json",
                                     update=Path(tmp) / "updated.json")  # fmt: skip
            updated = load_calibration(Path(tmp) / "updated.json").manipulator().model
        fresh = run_demo(seed=seed, evaluate=False, plat=platform("thesis", seed=seed,
                                                                  overrides=over))  # fmt: skip
        row = {
            "seed": seed, "shift_um": shift, "verdict": done.result.verdict,
            "offset_um": done.result.offset_um.tolist(),
            "after": done.update.verdict_after if done.update else None,
            "check_s": done.result.extra["duration_s"],
            "ap_stale_um": absolute_ap_um(model, seed + 1000, over),
            "ap_updated_um": absolute_ap_um(updated, seed + 1000, over),
            "ap_fresh_um": absolute_ap_um(fresh.models["polynomial"].model, seed + 1000, over),
        }  # fmt: skip
        rows.append(row)
        print(json.dumps(row), flush=True)
    for key in ("ap_stale_um", "ap_updated_um", "ap_fresh_um", "check_s"):
        print(key, round(float(np.mean([r[key] for r in rows])), 3))


if __name__ == "__main__":
    main()
