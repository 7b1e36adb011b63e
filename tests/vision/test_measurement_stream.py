"""MeasurementStream: the poses measured while they are fed, the same numbers as measure_poses."""

from __future__ import annotations

import numpy as np

from microcal import sim
from microcal.errors import FormatError
from microcal.vision.measurement import measure_poses
from microcal.vision.measurement_stream import MeasurementStream


def test_the_stream_measures_what_measure_poses_measures():
    plat = sim.platform("thesis", seed=5)
    m = plat.manipulator
    d = np.random.default_rng(1).uniform([0, 0, 0], [8000, 8000, 4800], (4, 3))
    frames = {}
    for i, di in enumerate(d):
        m.move_to_um(di)
        m.wait_until_stopped(plat.clock)
        plat.clock.sleep(5.0)
        for n, cam in plat.cameras.items():
            frames[(i, n)] = [cam.grab() for _ in range(1)]

    def load(i: int, n: str) -> list:
        if i == 2:  # a pose whose images cannot be read: failed with its reason
            raise FormatError("truncated image")
        return frames[(i, n)]

    poses = list(range(4))
    ticks: list[tuple[int, int]] = []
    stream = MeasurementStream(poses, d, load, plat.camera_models, plat.scene.board,
                               progress=lambda done, total: ticks.append((done, total)))  # fmt: skip
    for i in poses:
        stream.add(i)
    got = stream.results()
    want = measure_poses(poses, d, load, plat.camera_models, plat.scene.board)
    assert [r.status for r in got] == [r.status for r in want] == ["ok", "ok", "failed", "ok"]
    assert [r.reason for r in got] == [r.reason for r in want]
    np.testing.assert_array_equal([r.p_um for r in got], [r.p_um for r in want])
    np.testing.assert_array_equal([r.cov_um2 for r in got], [r.cov_um2 for r in want])
    assert ticks == [(k, 8) for k in range(1, 9)]


def test_a_stream_closed_early_ends_its_processes():
    plat = sim.platform("thesis", seed=5)
    stream = MeasurementStream([1, 2], np.zeros((2, 3)), lambda i, n: [], plat.camera_models,
                               plat.scene.board)  # fmt: skip
    stream.close()
    stream.close()  # twice is harmless
