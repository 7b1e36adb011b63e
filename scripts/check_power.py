"""Power and false alarms of ``microcal check`` over seeded trials (simulator, fast path).

For each trial a fresh simulated platform (seed FIRST + k) is checked twice with the same
calibration: first as it is (the reference check), then after a change: none, a 1 µm offset
in a random direction, or a 0.2 % scale change of a random joint. The positions are measured
by projecting the true end-effector through the true cameras with the rendered pipeline's
pixel noise and triangulating with the calibrated cameras (``ProjectedProbe``).

    python scripts/check_power.py demo-out/calibration.json --trials 100 --frames 20
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from microcal.formats.calibration_file import load_calibration
from microcal.procedures.check import CheckConfig, run_check
from microcal.sim import platform
from microcal.sim.synthetic_run import ProjectedProbe
from microcal.workflows.calibration_update import camera_models


def trial(cal, models, seed: int, change: str, frames: int, against: str) -> str:
    plat = platform("thesis", seed=seed)
    rng = np.random.default_rng(seed)
    probe = ProjectedProbe.on_platform(plat, rng, models)
    cfg = CheckConfig(frames=frames)
    m = cal.manipulator()
    reference = None
    if against == "reference":
        first = run_check(
            plat.manipulator, plat.clock, probe.measure_with_covariance, m, config=cfg
        )
        reference = (first.residual_um, first.covariance_um2)
    if change == "offset":
        v = rng.normal(size=3)
        plat.manipulator.mount_offset_um = v / np.linalg.norm(v) * 1.0
    elif change == "scale":
        plat.manipulator.joint_scale[rng.integers(3)] = 1.0 + rng.choice([-1, 1]) * 0.002
    result = run_check(plat.manipulator, plat.clock, probe.measure_with_covariance, m,
                       config=cfg, reference=reference)  # fmt: skip
    return result.verdict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("calibration")
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=5000)
    ap.add_argument("--against", choices=["reference", "calibration"], default="reference")
    args = ap.parse_args()
    cal = load_calibration(args.calibration)
    models = camera_models(cal)
    table = {}
    for change in ("none", "offset", "scale"):
        verdicts = [trial(cal, models, args.first_seed + k, change, args.frames, args.against)
                    for k in range(args.trials)]  # fmt: skip
        table[change] = {v: verdicts.count(v) / len(verdicts) for v in ("valid", "offset", "refit")}
        print(change, table[change], flush=True)
    print(json.dumps({"frames": args.frames, "against": args.against, "trials": args.trials,
                      "table": table}))  # fmt: skip


if __name__ == "__main__":
    main()
