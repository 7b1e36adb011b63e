"""The camera-model choice over seeds: what ``--camera-model auto`` picks, and how well.

Run from the repository root:
    .venv/bin/python scripts/camera_model_choice.py --seeds 10 [--poses 30]
For each of the presets telecentric and thesis and each seed: the model chosen per camera,
the affine (or chosen) model's reprojection RMS over the rendered noise floor, whether the
pinhole fit is ill-conditioned, and the 3D RMS error of measured poses with the chosen, the
true and the pinhole-fitted cameras. Simulator only.
"""

import argparse

import numpy as np

from microcal.experiments.camera_model_trial import camera_model_trial

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--seeds", type=int, default=10)
parser.add_argument("--first-seed", type=int, default=0)
parser.add_argument("--poses", type=int, default=30)
parser.add_argument("--presets", default="telecentric,thesis")
parser.add_argument("--frames-per-view", type=int, default=8)
args = parser.parse_args()

for preset in args.presets.split(","):
    picks, ratios, ill, r3d, m2 = [], [], [], [], []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        t = camera_model_trial(preset, seed, poses=args.poses, frames_per_view=args.frames_per_view)
        picks.append(set(t.chosen.values()))
        ratios.append(list(t.floor_ratio.values()))
        ill.append(all(t.pinhole_problem.values()))
        r3d.append(t.rms_3d_um)
        m2.append(t.mahalanobis_mean_sq)
        print(
            f"{preset} seed {seed}: chosen {t.chosen}; RMS/floor "
            + ", ".join(f"{n} {r:.3f}" for n, r in t.floor_ratio.items())
            + f"; pinhole {'ill-conditioned' if ill[-1] else 'fine'}"
            + (
                "; 3D RMS µm "
                + ", ".join(f"{k} {v:.3f}" for k, v in t.rms_3d_um.items())
                + f"; Mahalanobis mean square {t.mahalanobis_mean_sq:.2f}"
                if args.poses
                else ""
            ),
            flush=True,
        )
    chosen = [next(iter(p)) if len(p) == 1 else "mixed" for p in picks]
    ratio = np.array(ratios)
    print(
        f"== {preset}: chosen {dict(zip(*np.unique(chosen, return_counts=True), strict=True))}"
        f" of {args.seeds}; RMS/floor {ratio.min():.3f}..{ratio.max():.3f}; pinhole "
        f"ill-conditioned in {sum(ill)} of {args.seeds}"
    )
    if args.poses:
        for key in r3d[0]:
            v = [r[key] for r in r3d if key in r]
            print(f"   3D RMS with {key} cameras: median {np.median(v):.3f} µm, max {max(v):.3f}")
        ratio3 = [r["chosen"] / r["true"] for r in r3d]
        print(
            f"   chosen/true 3D RMS: max {max(ratio3):.3f}; Mahalanobis mean square median "
            f"{np.median(m2):.2f}"
        )
