"""VisionProbe.search_threads: searching each camera's frames in turn measures the same."""

from __future__ import annotations

import numpy as np

from microcal import sim
from microcal.vision.probe import VisionProbe


def _measured(search_threads: bool) -> np.ndarray:
    plat = sim.platform("thesis", seed=11)
    probe = VisionProbe(plat.cameras, plat.camera_models, plat.scene.board, frames=2,
                        search_threads=search_threads)  # fmt: skip
    m = plat.manipulator
    corners = plat.scene.board_placement(plat.clock.now_s()).points_world_um()
    for d in ([0, 0, 0], [2000, 0, 0], [0, 2000, 0], [0, 0, 2000]):  # where the board is
        shift = np.array(d, float)
        probe.learn_regions(shift, {n: c.model.project(corners + shift)
                                    for n, c in plat.cameras.items()})  # fmt: skip
    target = np.array([1000.0, 1000.0, 500.0])
    m.move_to_um(target)
    m.wait_until_stopped(plat.clock)
    return probe.measure(target)


def test_searching_in_turn_measures_what_the_threads_measure():
    a, b = _measured(True), _measured(False)
    assert np.all(np.isfinite(a))
    np.testing.assert_array_equal(a, b)
