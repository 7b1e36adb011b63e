"""A tool's tip measured on the ``thesis-tip`` platform: the figures of docs/vision.md.

Run from the repository root (about a minute per row with a pipette; under the shared lock
when it takes longer):

    .venv/bin/python scripts/thesis_tip_figures.py --spec tip:pipette:10:1 --poses 4
    .venv/bin/python scripts/thesis_tip_figures.py --spec tip:needle:20:5 --poses 6 --frames 5

The platform is ``thesis-tip`` (seed ``--seed``) with the tool of ``--spec``; the manipulator
visits ``--poses`` random joint commands over the thesis's travel (their own seed), waits 5 s
at each, grabs ``--frames`` frames per camera and measures the tip with the *true* camera
models (no stereo calibration: what is left is the tip's own error). Each pose's error against
the tip point's truth is split along the tool's axis and across it. Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from microcal.sim import platform
from microcal.vision.measurement import measure_one

#: Where the poses are drawn: the thesis's travel less 0.5 mm, µm.
LOW_UM = np.array([500.0, 500.0, 500.0])
HIGH_UM = np.array([7500.0, 7500.0, 4300.0])


def figures(spec: str, poses: int, frames: int, seed: int) -> dict[str, object]:
    """The tip's 3D error over the poses (see the module docstring)."""
    plat = platform("thesis-tip", seed=seed, overrides={"board": spec})
    m, models, tool = plat.manipulator, plat.camera_models, plat.scene.tool
    assert tool is not None  # a tip spec puts a tool on the manipulator
    rng = np.random.default_rng([seed, 5])
    errors, covs, failed, seconds = [], [], [], []
    for _ in range(poses):
        m.move_to_um(rng.uniform(LOW_UM, HIGH_UM))
        m.wait_until_stopped(plat.clock, timeout_s=60)
        plat.clock.sleep(5.0)
        grabbed = {n: [c.grab() for _ in range(frames)] for n, c in plat.cameras.items()}
        t0 = time.perf_counter()
        got = measure_one(grabbed, models, plat.scene.board, dict.fromkeys(models))
        seconds.append((time.perf_counter() - t0) / (frames * len(models)))
        if got.status != "ok":
            failed.append(got.reason)
            continue
        errors.append(got.p_um - m.true_position_um())
        covs.append(got.cov_um2)
    e = np.array(errors).reshape(-1, 3)
    along = e @ tool.axis
    across = e - along[:, None] * tool.axis
    chi2 = [float(x @ np.linalg.solve(c, x)) for x, c in zip(e, covs, strict=True)]
    return {
        "spec": spec, "seed": seed, "poses": poses, "frames": frames, "measured": len(e),
        "rms_3d_um": round(float(np.sqrt(np.mean(np.sum(e**2, axis=1)))), 2),
        "mean_along_axis_um": round(float(np.mean(along)), 2),
        "rms_along_axis_um": round(float(np.sqrt(np.mean(along**2))), 2),
        "rms_across_axis_um": round(float(np.sqrt(np.mean(np.sum(across**2, axis=1)))), 2),
        "mahalanobis_mean_sq": round(float(np.mean(chi2)), 1),
        "s_per_detection": round(float(np.median(seconds)), 2),
        "failed": failed,
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--spec", default="tip:pipette:10:1")
    parser.add_argument("--poses", type=int, default=4)
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(json.dumps(figures(args.spec, args.poses, args.frames, args.seed)))


if __name__ == "__main__":
    main()
