"""Simulated camera speed: one top and one side frame of the thesis preset (render, blur,
noise, quantisation), frame pairs per second on one core.

Baseline in the same run: the same renderer tracing every pixel of the frame instead of
only the region the board covers.
"""

from __future__ import annotations

import numpy as np

from microcal import sim
from microcal.sim.render import render_placement

from .harness import Case, best_time_s

N_PAIRS = 40


def run() -> list[Case]:
    plat = sim.platform("thesis", seed=0)
    rng = np.random.default_rng(1)
    poses = rng.uniform([0, 0, 0], [8000, 8000, 4800], (N_PAIRS, 3))

    def grab_pairs() -> None:
        for d in poses:
            plat.manipulator.move_to_um(d)
            plat.manipulator.wait_until_stopped(plat.clock)
            for cam in plat.cameras.values():
                cam.grab()

    t_pairs = best_time_s(grab_pairs, 3) / N_PAIRS

    def full_frame_pair() -> None:
        t = plat.clock.now_s()
        for cam in plat.cameras.values():
            placement = plat.scene(t)[0]
            w, h = cam.model.image_size_px
            render_placement(
                cam.model, placement, (0, 0, w, h), supersample=cam.formation.supersample
            )

    t_full = best_time_s(full_frame_pair, 2)
    rate = 1.0 / t_pairs
    return [
        Case(
            name="render a top + side frame pair (thesis preset)",
            unit="pairs/s",
            value=rate,
            baseline_name="trace every pixel",
            baseline=1.0 / t_full,
            goal=">= 20 pairs/s on one core",
            meets_goal=rate >= 20,
            details={"time_per_pair_s": t_pairs},
        )
    ]
