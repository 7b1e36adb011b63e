"""Motion noise and reversal error with memory in the simulated manipulator."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import sim
from microcal.control.feedforward import APPROACH_UM
from microcal.errors import InputError
from microcal.experiments.study import ExactFeedForward
from microcal.metrics.iso9283 import pose_repeatability
from microcal.procedures.evaluation import run_multi_directional
from microcal.sim.motion import MotionNoise, PlayHysteresis, play_radii_um
from microcal.sim.platforms import THESIS_PLAY


def _settle(plat: sim.SimPlatform, d: list[float]) -> np.ndarray:
    plat.manipulator.move_to_um(d)
    plat.manipulator.wait_until_stopped(plat.clock)
    plat.clock.sleep(60.0)
    return plat.truth_position_um()


def test_a_long_approach_gives_the_sign_and_a_short_reversal_less() -> None:
    play = PlayHysteresis(np.tile(play_radii_um(4.0), (3, 1)), np.full((3, 5), 0.2))
    x = np.full(3, 100.0)
    state = play.start_state_um(x)
    np.testing.assert_allclose(play.direction(state, x), 1.0, atol=1e-12)
    down = x - 1.0  # a 1 µm reversal turns only the small operators over
    short = play.direction(play.moved(state, down), down)
    far = x - 50.0
    long = play.direction(play.moved(state, far), far)
    np.testing.assert_allclose(long, -1.0, atol=1e-12)
    assert np.all(short > -0.6)
    assert np.all(short < 0.9)
    # minor loop: back up after the short reversal is not back to +1 either
    back = play.direction(play.moved(play.moved(state, down), x), x)
    np.testing.assert_allclose(back, 1.0, atol=1e-12)  # the small ones saturate again


def test_the_fixed_approach_saturates_every_play_the_simulator_draws() -> None:
    assert THESIS_PLAY.saturation_um() <= APPROACH_UM
    for seed in range(20):
        draw = sim.platform("population", seed=seed).population
        assert draw is not None
        assert draw.play.saturation_um() <= APPROACH_UM


def test_motion_noise_ends_on_the_step_grid_and_refuses_bad_sizes() -> None:
    noise = MotionNoise(step_um=(0.05, 0.05, 0.05))
    end = noise.end_um(np.zeros(3), np.array([1.01, -2.0, 0.0]), np.random.default_rng(0))
    np.testing.assert_allclose(end, [1.0, -2.0, 0.0], atol=1e-12)
    with pytest.raises(InputError, match="scatter_um"):
        MotionNoise(scatter_um=(-1.0, 0.0, 0.0))


def test_thesis_motion_is_ideal_and_thesis_real_is_not() -> None:
    ideal = sim.platform("thesis", seed=4)
    real = sim.platform("thesis-real", seed=4)
    assert ideal.manipulator.motion is None
    assert ideal.manipulator.truth.play is None
    a = [_settle(ideal, [4000.0, 4000.0, 2400.0]) for _ in range(2)]
    np.testing.assert_array_equal(a[0], a[1])  # a repeated command lands on the same point
    for plat in (ideal, real):
        _settle(plat, [3000.0, 3000.0, 2000.0])
    b = [_settle(real, [3000.0 + 2.0 * (k % 2), 3000.0, 2000.0]) for k in range(6)]
    assert np.ptp(np.array(b)[::2, 1]) > 1e-3  # the scatter moves every axis


def test_a_rig_file_switch_turns_it_on_and_off() -> None:
    on = sim.platform("thesis", seed=0, overrides={"manipulator.real_motion": True})
    off = sim.platform("population", seed=0, overrides={"manipulator.real_motion": False})
    assert on.manipulator.motion is not None
    assert on.manipulator.truth.play is not None
    assert off.manipulator.motion is None
    assert off.manipulator.truth.play is None


def test_thesis_real_repeatability_and_vap_by_truth_are_in_the_sources_range() -> None:
    plat = sim.platform("thesis-real", seed=0)
    m = plat.manipulator
    ff = ExactFeedForward(m, plat.clock, lambda d, s, t: m.truth.position_um(d, s, t))
    arrivals = []
    for k in range(10):  # the same pose from alternating sides, the fixed approach each time
        ff.move_to_position_um(ff.home_um() + np.array([4000.0, 4000.0, 2000.0]))
        m.wait_until_stopped(plat.clock)
        plat.clock.sleep(60.0)
        arrivals.append(plat.truth_position_um())
        _settle(plat, [4000.0 + (-300.0 if k % 2 else 300.0), 4000.0, 2000.0])
    rp = pose_repeatability(np.array(arrivals))
    assert 0.02 < rp < 0.3
    vap = run_multi_directional(m, plat.clock, None, {"optimal": ff}, cycles=3, settle_s=60.0,
                                truth=plat.truth_position_um)["truth"]["optimal"]  # fmt: skip
    assert 0.0 < vap.vap_um <= 0.3
