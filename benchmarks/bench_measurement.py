"""Measurement speed: detection + triangulation of a run's image pairs at the thesis
preset's resolution, pairs per second.

microcal: the board searched in a region predicted from the commanded joints (after the
first poses), coarse-to-fine otherwise, virtual points triangulated optimally.
Baseline in the same run: the thesis's appendix A (whole-image ``findChessboardCorners``
with adaptive thresholding, ``cornerSubPix`` with a 5 x 5 window, mean of the corners) and
appendix B (one SVD per point). A second case: the cameras measured in parallel (one forked
process each) against one process, the same numbers either way.
"""

from __future__ import annotations

import cv2
import numpy as np

from microcal import sim
from microcal.vision.measurement import measure_poses
from microcal.vision.targets import parse_target

from .bench_triangulation import thesis_appendix_b_loop
from .harness import Case, best_time_s

N_POSES = 60
N_BASELINE = 20


def thesis_appendix_a(image: np.ndarray) -> np.ndarray | None:
    found, corners = cv2.findChessboardCorners(image, (4, 3), flags=cv2.CALIB_CB_ADAPTIVE_THRESH)
    if not found:
        return None
    term = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1)
    corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1), term)
    return np.asarray(corners).reshape(-1, 2).mean(axis=0)


def run() -> list[Case]:
    plat = sim.platform("thesis", seed=5)
    board = parse_target("chessboard:4x3:400")
    d = np.random.default_rng(6).uniform([0, 0, 0], [8000, 8000, 4800], (N_POSES, 3))
    frames = {}
    for i, di in enumerate(d):
        plat.manipulator.move_to_um(di)
        plat.manipulator.wait_until_stopped(plat.clock)
        plat.clock.sleep(5.0)
        for n, cam in plat.cameras.items():
            frames[(i, n)] = [cam.grab()]
    models = plat.camera_models

    def ours(workers: int = 1) -> None:
        res = measure_poses(list(range(N_POSES)), d, lambda i, n: frames[(i, n)], models, board,
                            workers=workers)  # fmt: skip
        assert all(r.status == "ok" for r in res)

    def thesis() -> None:
        for i in range(N_BASELINE):
            q = [thesis_appendix_a(frames[(i, n)][0]) for n in models]
            P = [m.P for m in models.values()]
            thesis_appendix_b_loop(P[0], P[1], q[0][None, :], q[1][None, :])

    t_ours = best_time_s(ours, 3) / N_POSES
    t_thesis = best_time_s(thesis, 1) / N_BASELINE
    t_parallel = best_time_s(lambda: ours(len(models)), 3) / N_POSES
    return [
        Case(
            name="measure image pairs (detect + triangulate)",
            unit="pairs/s",
            value=1.0 / t_ours,
            baseline_name="thesis appendix A + B",
            baseline=1.0 / t_thesis,
            details={"time_per_pair_s": t_ours, "thesis_time_per_pair_s": t_thesis},
        ),
        Case(
            name="measure image pairs, one process per camera",
            unit="pairs/s",
            value=1.0 / t_parallel,
            baseline_name="one process",
            baseline=1.0 / t_ours,
            details={"time_per_pair_s": t_parallel},
        ),
    ]
