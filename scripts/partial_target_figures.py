"""Figures of the 3D measurement of an end-effector whose marked target is partly out of
the field, against the same target seen whole (the simulator's truth, the true cameras).

Usage: python scripts/partial_target_figures.py [--spec SPEC] [--points N] [--frames K] [--seed S]

Each case places the target's centre (the end-effector) at N points in {G}: "whole" where
both cameras see every feature, "top cut" / "side cut" where that camera's image edge cuts
off part of the target, "both cut" where both do. The points of a case are measured from K frames
per camera each as ``microcal measure`` measures a run's poses (the frame-to-frame scatter
pooled over the case); the 3D error is the measured point less the
true centre, with its predicted standard deviation from the measurement's covariance.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from microcal import sim
from microcal.sim.platforms import MARKED_END_EFFECTOR
from microcal.sim.render import Placement
from microcal.vision.measurement import measure_poses
from microcal.vision.targets import parse_target

#: The blur (sigma, px) up to which the hollow dots' holes are resolved: points nearer focus.
MAX_BLUR_PX = 1.9


def _inside(model, pts, margin_px):
    w, h = model.image_size_px
    q = model.project(pts)
    return (q[:, 0] > margin_px) & (q[:, 1] > margin_px) & (q[:, 0] < w - margin_px) & \
        (q[:, 1] < h - margin_px)  # fmt: skip


def cases(plat, target, n, rng):
    """{case: list of end-effector points (3,) µm}: points of a grid over {G} sorted by
    what each camera sees of the target there (every feature; its markers and 30-90 % of
    the features), n drawn from each."""
    models = [plat.cameras["top"].model, plat.cameras["side"].model]
    base = plat.truth_position_um()
    pts = target.points_um() - target.centre_um
    cols = np.array([c for c, _ in target.markers])
    rows = np.array([r for _, r in target.markers])
    marks = pts[rows * target.cols + cols] if target.markers else pts
    out: dict[str, list[np.ndarray]] = {"whole": [], "top cut": [], "side cut": [], "both cut": []}
    grid = np.stack(np.meshgrid(np.arange(-40000, 40001, 250.0), np.arange(-40000, 40001, 250.0),
                                indexing="ij"), axis=-1).reshape(-1, 2)  # fmt: skip
    for _ in range(n):
        z = base[2] + rng.uniform(-300, 300)
        kinds: dict[str, list[np.ndarray]] = {k: [] for k in out}
        for xy in grid[rng.permutation(len(grid))[:4000]]:
            p = np.array([*(base[:2] + xy), z])
            share = [float(np.mean(_inside(m, pts + p, 2.0))) for m in models]
            marked = [bool(np.all(_inside(m, marks + p, 30.0))) for m in models]
            placed = Placement(target, np.eye(3), p - target.centre_um)
            sharp = all(cam._blur_sigma(placed) <= MAX_BLUR_PX for cam in plat.cameras.values())
            if not all(marked) or not sharp:
                continue
            cut = [0.3 <= s <= 0.9 for s in share]
            whole = [s == 1.0 for s in share]
            kind = (
                "whole"
                if all(whole)
                else "top cut"
                if cut[0] and whole[1]
                else "side cut"
                if whole[0] and cut[1]
                else "both cut"
                if all(cut)
                else ""
            )
            if kind:
                kinds[kind].append(p)
        for k, v in kinds.items():
            if v:
                out[k].append(v[0])
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spec", default=MARKED_END_EFFECTOR)
    ap.add_argument("--points", type=int, default=8)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    target = parse_target(args.spec)
    plat = sim.platform("thesis", seed=args.seed, overrides={"board": args.spec})
    plat.scene.show_board = False
    models = plat.camera_models
    rng = np.random.default_rng(args.seed)
    print(f"target {args.spec}, {args.frames} frames per camera and point, seed {args.seed}")
    for case, points in cases(plat, target, args.points, rng).items():
        t0 = time.time()
        frames = {}
        for k, p in enumerate(points):
            plat.scene.fixed = Placement(target, np.eye(3), p - target.centre_um)
            for n, cam in plat.cameras.items():
                frames[(k, n)] = [cam.grab() for _ in range(args.frames)]
        got = measure_poses(list(range(len(points))), np.array(points),
                            lambda k, n, f=frames: f[(k, n)], models, target)  # fmt: skip
        errs, sds, seen = [], [], {n: [] for n in models}
        for m, p in zip(got, points, strict=True):
            if m.status != "ok":
                print(f"  {case}: failed: {m.reason}")
                continue
            errs.append(m.p_um - p)
            sds.append(m.std_um)
            for n in models:
                seen[n].append(len(m.corners_px.get(n, [])))
        if not errs:
            continue
        e, s = np.array(errs), np.array(sds)
        total = len(target.points_um())
        share = ", ".join(f"{n} {np.mean(v) / total:.0%}" for n, v in seen.items())
        print(
            f"{case:9s} {len(e)} points; features seen ({share}); 3D error RMS "
            f"x/y/z {np.sqrt(np.mean(e**2, axis=0)).round(3)} µm, |e| RMS "
            f"{np.sqrt(np.mean(np.sum(e**2, axis=1))):.3f} µm; predicted SD "
            f"{np.sqrt(np.mean(s**2, axis=0)).round(3)} µm ({time.time() - t0:.0f} s)"
        )


if __name__ == "__main__":
    main()
