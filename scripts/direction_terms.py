"""Reversal error and the approach-direction terms: the demo with and without them, per seed.

Run from the repository root:
    .venv/bin/python scripts/direction_terms.py --seeds 3 [--approach-um 200] [--quick]
For each seed of the thesis preset: the full demo with the polynomial model as before and
with the terms sx, sy, sz (driven with a fixed approach from below), and the optimal
compensator's pose accuracy (AP mean / worst) and multi-directional variation (vAP mean /
worst, ISO 9283 7.2.3), by ground truth. Simulator only.
"""

import argparse

from microcal.experiments.demo import run_demo

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--seeds", type=int, default=3)
parser.add_argument("--first-seed", type=int, default=0)
parser.add_argument("--approach-um", type=float, default=0.0)
parser.add_argument("--quick", action="store_true", help="40 poses, 2 frames, 1 cycle")
args = parser.parse_args()
size = {"poses": 40, "frames_per_pose": 2, "cycles": 1} if args.quick else {}

for seed in range(args.first_seed, args.first_seed + args.seeds):
    for terms in (False, True):
        demo = run_demo(seed, direction_terms=terms, approach_um=args.approach_um, **size)
        truth = demo.evaluation["pose_accuracy"]["truth"]
        model = demo.manipulator.model
        terms_used = [n for a in range(3) for n, _, _ in model.axis_terms(a) if n[0] == "s"]
        print(
            f"seed {seed} direction terms {'on ' if terms else 'off'}: "
            + "; ".join(
                f"{c} AP {f['mean_ap_p_um']:.2f}/{f['max_ap_p_um']:.2f} "
                f"vAP {f['vap_um']:.2f}/{f['max_vap_um']:.2f}"
                for c, f in truth.items()
            )
            + f"; validation {demo.models['polynomial'].validation['mean_um']:.2f} µm"
            + f" (oracle {demo.oracle['mean']:.2f})"
            + f"; terms {sorted(set(terms_used))}",
            flush=True,
        )
