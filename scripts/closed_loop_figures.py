"""The closed loop's figures on the thesis preset (docs/compensation.md), platform by platform.

    python scripts/closed_loop_figures.py [--seeds 101 102 103 104] [--cycles 3]
                                          [--tolerance-um 0.5]

Runs the demo once (seed 0, 170 poses, rendered: its stereo calibration and polynomial
model), then on each platform seed the ISO 9283 pose-accuracy test at the Table 5-2 poses
with the optimal compensator (open loop) and with the closed loop. The probe projects the
true tip through the true cameras with the rendered pipeline's pixel noise and triangulates
with the demo's calibrated cameras (``ProjectedProbe.on_platform``), so the
cameras' calibration error is in every measurement. Prints AP mean / worst by truth, how
often the loop's 95 % region held the truth, and iterations and frames per target.
Simulator only.
"""

from __future__ import annotations

import argparse

import numpy as np

from microcal import sim
from microcal.control.closed_loop import ClosedLoop
from microcal.control.feedforward import FeedForward, extra_inputs_reader
from microcal.control.visual_servo import ServoConfig
from microcal.experiments.demo import run_demo
from microcal.procedures.evaluation import run_pose_accuracy
from microcal.sim.synthetic_run import ProjectedProbe


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104])
    parser.add_argument("--cycles", type=int, default=3)
    parser.add_argument("--tolerance-um", type=float, default=0.5)
    args = parser.parse_args()
    demo = run_demo(seed=0, poses=170, evaluate=False)
    model = demo.models["polynomial"].model
    calibrated = demo.calibration.models()
    print("seed  open mean/worst  closed mean/worst  in 95 %  iterations  frames")
    for seed in args.seeds:
        plat = sim.platform("thesis", seed=seed)
        probe = ProjectedProbe.on_platform(plat, np.random.default_rng(seed), calibrated)
        extra = extra_inputs_reader(model, {})
        loop = ClosedLoop(plat.manipulator, model, probe.measure_with_covariance, plat.clock,
                          extra, ServoConfig(tolerance_um=args.tolerance_um),
                          truth=plat.truth_position_um)  # fmt: skip
        ff = FeedForward(plat.manipulator, model, "optimal", extra, plat.clock)
        r = run_pose_accuracy(plat.manipulator, plat.clock, probe,
                              {"optimal": ff, "closed_loop": loop}, cycles=args.cycles,
                              truth=plat.truth_position_um)["truth"]  # fmt: skip
        s = loop.summary()
        o, c = r["optimal"], r["closed_loop"]
        print(f"{seed:4d}  {o['mean_ap_p_um']:5.2f} / {o['max_ap_p_um']:5.2f}    "
              f"{c['mean_ap_p_um']:5.2f} / {c['max_ap_p_um']:5.2f}      "
              f"{s['truth_in_measured_95']:6.0%}  {s['iterations_mean']:10.1f}  "
              f"{s['frames_mean']:6.0f}")  # fmt: skip


if __name__ == "__main__":
    main()
