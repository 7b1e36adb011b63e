"""The demo's evaluation dealt to forked processes: the same moves, the same ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import sim
from microcal._parallel import can_fork
from microcal.experiments.demo_evaluation import (
    ClockOnlyProbe,
    DemoTests,
    deal_units,
    run_demo_tests,
    units_of,
)
from microcal.procedures.evaluation import RunOptions
from microcal.thesis.experiment import TABLE_5_2_POSES_UM
from microcal.vision.probe import VisionProbe


def test_units_are_dealt_heaviest_first_and_all_once():
    units = units_of(["uncalibrated", "matrix", "optimal"], decoupling=True)
    weights = {u: 16 if u[0] == "pose accuracy" else 51 for u in units}
    dealt = deal_units(weights, 2)
    assert sorted(u for part in dealt for u in part) == sorted(units)
    loads = [sum(weights[u] for u in part) for part in dealt]
    assert max(loads) - min(loads) <= 16
    assert all(part == sorted(part, key=units.index) for part in dealt)  # in the run's order
    assert sorted(deal_units(weights, 10)) == sorted([[u] for u in units])
    assert deal_units({units[0]: 1}, 2) == [[units[0]]]


def test_the_clock_only_probe_takes_the_frames_time():
    plat = sim.platform("thesis", seed=3)
    probe = VisionProbe(plat.cameras, plat.camera_models, plat.scene.board, frames=2)
    t0 = plat.clock.now_s()
    probe.measure(np.zeros(3))
    took = plat.clock.now_s() - t0
    t1 = plat.clock.now_s()
    assert np.all(np.isnan(ClockOnlyProbe(plat.cameras, 2).measure(np.zeros(3))))
    assert plat.clock.now_s() - t1 == pytest.approx(took, abs=1e-9)


def test_frames_let_pass_draw_what_grabs_draw():
    """A platform that grabs three frames and one that lets two pass: the third frame is the
    same, pixel for pixel (the noise stream is where the grabs leave it)."""
    grabbed, passed = sim.platform("thesis", seed=6), sim.platform("thesis", seed=6)
    for name in grabbed.cameras:
        a, b = grabbed.cameras[name], passed.cameras[name]
        for _ in range(2):
            a.grab_lazy()
            b.pass_frame()
        np.testing.assert_array_equal(a.grab(), b.grab())
    assert grabbed.clock.now_s() == passed.clock.now_s()


def _tests(plat: sim.SimPlatform) -> DemoTests:
    m = plat.manipulator
    options = RunOptions(settle_s=0.5, truth=m.true_position_um, progress=None)
    return DemoTests(m, plat.clock, {"uncalibrated": None}, TABLE_5_2_POSES_UM[:2], 1, 2, options)


def _probe(plat: sim.SimPlatform) -> VisionProbe:
    """A probe that knows where the board is (from its true projection at four poses)."""
    probe = VisionProbe(plat.cameras, plat.camera_models, plat.scene.board, frames=1)
    m = plat.manipulator
    for d in ([0, 0, 0], [3000, 0, 0], [0, 3000, 0], [0, 0, 3000]):
        m.move_to_um(np.array(d, float))
        m.wait_until_stopped(plat.clock)
        corners = plat.scene.board_placement(plat.clock.now_s()).points_world_um()
        probe.learn_regions(np.array(d, float),
                            {n: c.model.project(corners) for n, c in plat.cameras.items()})  # fmt: skip
    return probe


@pytest.mark.skipif(not can_fork(), reason="this system does not fork safely")
def test_forked_units_see_the_same_device_as_the_run_in_turn():
    runs = []
    for workers in (1, 2):
        plat = sim.platform("thesis", seed=3)
        pa, dec = run_demo_tests(_tests(plat), _probe(plat), plat.cameras, workers)
        assert dec is not None
        runs.append((pa, dec, plat.clock.now_s(), plat.manipulator.true_position_um()))
    (pa1, dec1, t1, p1), (pa2, dec2, t2, p2) = runs
    # the platform ends where the run in turn leaves it; the ground truth is the same numbers
    assert t1 == t2
    np.testing.assert_array_equal(p1, p2)
    truth1, truth2 = pa1["truth"]["uncalibrated"].poses, pa2["truth"]["uncalibrated"].poses
    for a, b in zip(truth1, truth2, strict=True):
        np.testing.assert_array_equal(a.mean_arrival_um, b.mean_arrival_um)
    np.testing.assert_array_equal(dec1["truth"]["uncalibrated"].samples_um,
                                  dec2["truth"]["uncalibrated"].samples_um)  # fmt: skip
    # the cameras measured in the forked processes: the frames the run in turn measures (the
    # frames left out drew what grabbing them draws), the board maybe searched in another
    # region (one frame per camera: about 2 µm RMS from the truth)
    seen1, seen2 = (
        dec1["vision"]["uncalibrated"].samples_um,
        dec2["vision"]["uncalibrated"].samples_um,
    )
    assert np.abs(seen1 - seen2).max() < 0.05
    for pa, dec in ((pa1, dec1), (pa2, dec2)):
        assert set(pa["vision"]) == set(dec["vision"]) == {"uncalibrated"}
        seen = dec["vision"]["uncalibrated"].samples_um
        true = dec["truth"]["uncalibrated"].samples_um
        assert np.all(np.isfinite(seen))
        assert np.sqrt(np.mean(np.sum((seen - true) ** 2, axis=1))) < 5.0
        assert np.isfinite(pa["vision"]["uncalibrated"].mean_ap_p_um)
