"""Simulated camera speed, against the previous code in the same run (there is no outside
baseline for this renderer).

- one thesis frame's detection region: the board's box in the top camera (what the detector
  reads), rendered (lens distortion, 2 x 2 box-filtered subsamples), ms;
- a whole frame traced pixel by pixel (what a full-frame render costs), ms;
- a top + side frame pair grabbed (render, blur, noise, quantisation) at random poses, on
  one core, pairs/s.

The previous code (``benchmarks/previous.py``) runs the same ``measure`` in a child process;
the two are run in turn, twice each, and each keeps its best.
"""

from __future__ import annotations

import numpy as np

from microcal import sim
from microcal.sim import render

from .harness import Case, best_time_s
from .previous import measure_previous, previous_ref

N_PAIRS = 40
POSE_UM = (4000.0, 4000.0, 2400.0)


def measure() -> dict[str, float]:
    """Timings with whichever microcal is importable (this one or the previous)."""
    # the cameras' own path: render_region where it exists, render_placement before it
    draw = getattr(render, "render_region", render.render_placement)
    plat = sim.platform("thesis", seed=0)
    plat.manipulator.move_to_um(np.array(POSE_UM))
    plat.manipulator.wait_until_stopped(plat.clock)
    cam = plat.cameras["top"]
    placement = plat.scene(plat.clock.now_s())[0]
    sigma = cam.formation.blur_sigma_px
    roi = render.roi_of(cam.model, placement, 4.0 * sigma + 3.0)
    assert roi is not None
    s = cam.formation.supersample
    offset = np.array([0.1, -0.2])
    draw(cam.model, placement, roi, supersample=s, offset_px=offset)  # the grid, cached
    t_region = best_time_s(
        lambda: [draw(cam.model, placement, roi, supersample=s, offset_px=offset)
                 for _ in range(50)], 5
    ) / 50  # fmt: skip
    w, h = cam.model.image_size_px
    t_full = best_time_s(lambda: draw(cam.model, placement, (0, 0, w, h), supersample=s), 3)
    rng = np.random.default_rng(1)
    poses = rng.uniform([0, 0, 0], [8000, 8000, 4800], (N_PAIRS, 3))

    def grab_pairs() -> None:
        for d in poses:
            plat.manipulator.move_to_um(d)
            plat.manipulator.wait_until_stopped(plat.clock)
            for c in plat.cameras.values():
                c.grab()

    t_pair = best_time_s(grab_pairs, 3) / N_PAIRS
    return {
        "region_ms": t_region * 1e3,
        "region_px": float((roi[2] - roi[0]) * (roi[3] - roi[1])),
        "full_frame_ms": t_full * 1e3,
        "pair_s": t_pair,
    }


def run() -> list[Case]:
    rounds = [(measure(), measure_previous("bench_rendering")) for _ in range(2)]
    new = {k: min(r[0][k] for r in rounds) for k in rounds[0][0]}
    olds = [r[1] for r in rounds if r[1] is not None]
    old = {k: min(o[k] for o in olds) for k in olds[0]} if olds else None
    nan = float("nan")
    ref = f"previous code {previous_ref()[:10]}"

    def was(key: str) -> float:
        return old[key] if old is not None else nan

    pairs = 1.0 / new["pair_s"]
    return [
        Case(
            name="render one thesis frame's detection region (top camera)",
            unit="ms",
            value=new["region_ms"],
            baseline_name=ref,
            baseline=was("region_ms"),
            goal="<= 2 ms",
            meets_goal=new["region_ms"] <= 2.0,
            details={"region_px": new["region_px"]},
        ),
        Case(
            name="render a whole thesis frame (every pixel, top camera)",
            unit="ms",
            value=new["full_frame_ms"],
            baseline_name=ref,
            baseline=was("full_frame_ms"),
            goal="no slower than the previous code",
            meets_goal=None if old is None else new["full_frame_ms"] <= old["full_frame_ms"],
        ),
        Case(
            name="grab a top + side frame pair (thesis preset)",
            unit="pairs/s",
            value=pairs,
            baseline_name=ref,
            baseline=1.0 / was("pair_s"),
            goal=">= 20 pairs/s on one core",
            meets_goal=pairs >= 20,
            details={"time_per_pair_s": new["pair_s"]},
        ),
    ]
