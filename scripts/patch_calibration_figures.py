"""The whole calibration on the simulated one-camera ``patch`` rig over several seeds.

Runs :func:`microcal.experiments.patch_demo.run_patch_demo` per seed and prints, per seed and
on average: the slide's scale and rotation errors, the tips' error against ground truth (RMS
per axis of {M}) and its mean square over the stated covariance, the polynomial model's
held-out error, ISO 9283 AP at the cube P1-P5 by truth and by the one-camera probe
(uncalibrated, matrix, optimal, closed loop), AP by truth at random points filling the
working volume, and the rig's simulated time per stage.

    PYTHONPATH=src python scripts/patch_calibration_figures.py --seeds 5 [--first 0] [--poses 80]
        [--method sweep|stack]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from microcal.experiments.patch_demo import run_patch_demo

CONDITIONS = ("uncalibrated", "matrix", "optimal", "closed_loop")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--poses", type=int, default=80)
    ap.add_argument("--cycles", type=int, default=3)
    ap.add_argument("--method", choices=("sweep", "stack"), default="sweep")
    args = ap.parse_args()
    rows = []
    for seed in range(args.first, args.first + args.seeds):
        t0 = time.perf_counter()
        r = run_patch_demo(seed, args.poses, cycles=args.cycles, method=args.method)
        pa = r.evaluation.pose_accuracy or {}
        vol = (r.volume_accuracy or {}).get("truth", {})
        row = {
            "seed": seed,
            "scale %": r.scope_errors["scale_error_pct"],
            "rot deg": r.scope_errors["rotation_error_deg"],
            "found": f"{int(r.run.ok.sum())}/{len(r.run.ok)}",
            "tip x": r.measurement_rms_axis_um[0],
            "tip y": r.measurement_rms_axis_um[1],
            "tip z": r.measurement_rms_axis_um[2],
            "chi2/3": r.mahalanobis_mean_sq / 3,
            "poly held-out": float(np.asarray(r.models["polynomial"].validation["mean_um"])),
            **{
                f"AP truth {c}": pa["truth"][c].mean_ap_p_um for c in CONDITIONS if c in pa["truth"]
            },
            **{
                f"AP vision {c}": pa["vision"][c].mean_ap_p_um
                for c in CONDITIONS
                if c in pa["vision"]
            },
            **{f"AP volume {c}": vol[c].mean_ap_p_um for c in CONDITIONS if c in vol},
            **{f"max AP volume {c}": vol[c].max_ap_p_um for c in CONDITIONS if c in vol},
            "rig slide s": r.rig_s.get("slide", 0.0),
            "rig acq+meas s": r.rig_s.get("acquisition and measurement", 0.0),
            "rig fit s": r.rig_s.get("identification", 0.0),
            "rig calibration min": r.calibration_rig_s / 60,
            "rig evaluation min": r.rig_s.get("evaluation", 0.0) / 60,
            "wall s": time.perf_counter() - t0,
        }
        if r.evaluation.closed_loop is not None:
            row["closed-loop corrections"] = r.evaluation.closed_loop.iterations_mean
        rows.append(row)
        print(" | ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                         for k, v in row.items()), flush=True)  # fmt: skip
    keys = [k for k in rows[0] if k not in ("seed", "found")]
    print("\n| figure | mean over seeds | worst seed |\n| --- | --- | --- |")
    for k in keys:
        vals = np.array([row[k] for row in rows if k in row], dtype=float)
        print(f"| {k} | {vals.mean():.4g} | {vals.max():.4g} |")


if __name__ == "__main__":
    main()
