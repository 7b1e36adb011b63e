"""Grow the random design with the adaptive design's frames per pose, beside a study of it.

    python scripts/adaptive_equal_frames.py STUDY_DIR [--frames 20] [--step 10]

For each seed of an adaptive study (study.json of ``microcal study --design adaptive``),
the random design on a platform of the same seed is grown in steps of ``--step`` poses (10,
as the study does) with the
adaptive run's frames per pose, and the fewest of its poses whose true tip error is at most
the adaptive run's is printed: the design's own share of the saving, apart from the frames.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from microcal.experiments.adaptive_run import poses_to_match, random_curve
from microcal.experiments.demo import demo_design_seed
from microcal.experiments.study import StudyConfig, adaptive_settings
from microcal.procedures.acquisition import AcquisitionConfig
from microcal.sim import platform


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study", type=Path)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--step", type=int, default=10)
    args = parser.parse_args()
    study = json.loads((args.study / "study.json").read_text(encoding="utf-8"))
    ratios, used, needed = [], [], []
    for run in study["runs"]:
        seed, reached = run["seed"], run["tip_error_p95_um"]["adaptive"]
        config = StudyConfig(design="adaptive", until_um=run["adaptive"]["until_um"])
        acq = AcquisitionConfig(
            approach_um=config.approach_um, approach_seed=demo_design_seed(seed)
        )
        plat = platform(study["preset"], seed=seed)
        curve = random_curve(plat, seed, list(range(20, 301, args.step)), acq, config.settle_s,
                             args.frames, adaptive_settings(config, seed))  # fmt: skip
        need = poses_to_match(curve, reached)
        ratio = run["n_poses"] / need if need else float("nan")
        ratios.append(ratio)
        used.append(run["n_poses"])
        needed.append(need if need else np.nan)
        print(
            f"seed {seed}: adaptive {run['n_poses']} poses, tip p95 {reached:.3f} µm; random "
            f"({args.frames} frames) needs {need} poses; ratio {ratio:.2f}",
            flush=True,
        )
    print(
        f"median ratio {np.nanmedian(ratios):.3f} over {len(ratios)} seeds "
        f"({int(np.isnan(ratios).sum())} not matched within 300 poses); median poses: adaptive "
        f"{np.median(used):g}, random {np.nanmedian(needed):g}"
    )


if __name__ == "__main__":
    main()
