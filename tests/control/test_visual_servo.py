"""Visual servoing (control/visual_servo.py) and the closed-loop condition, on the simulated
manipulator measured by its truth plus seeded noise of a known covariance (no rendering)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from microcal.control.closed_loop import ClosedLoop
from microcal.control.visual_servo import (
    ServoConfig,
    probability_within,
    servo,
    smallest_confirmable_um,
)
from microcal.errors import DetectionError, LimitError, MoveError
from microcal.kinematics import fit_matrix_model
from microcal.sim import platform

STD_UM = np.array([0.3, 0.2, 0.7])  # per frame: the averaged noise is STD_UM / sqrt(frames)


def _rig(seed: int):
    plat = platform("thesis", seed)
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.0, [8000.0, 8000.0, 4800.0], (60, 3))
    truth = plat.manipulator.truth
    model = fit_matrix_model(d, truth.position_um(d))  # off by the curvature: a few µm
    state = {"lost": False}

    def measure(d_um, frames):
        if state["lost"]:
            return np.full(3, np.nan), np.full((3, 3), np.nan)
        cov = np.diag((STD_UM / np.sqrt(frames)) ** 2)
        return plat.truth_position_um() + rng.multivariate_normal(np.zeros(3), cov), cov

    return plat, model, measure, state


def test_the_probability_of_the_tolerance_ball_matches_the_chi_square():
    for r in (0.5, 1.0, 2.0):  # centred isotropic: P = chi2_3 cdf of (r / sigma)^2
        p = probability_within(np.zeros(3), np.eye(3) * 0.5**2, r)
        assert p == pytest.approx(scipy.stats.chi2.cdf((r / 0.5) ** 2, 3), abs=0.02)
    assert probability_within(np.array([3.0, 0, 0]), np.eye(3) * 0.01, 0.5) == 0.0


def test_the_smallest_confirmable_tolerance_is_the_chi_square_radius():
    # Metric: radius, µm; isotropic sigma 0.5 µm: r = sigma * sqrt(chi2_3 quantile); the
    # 4000 fixed draws give it to about 1 %.
    r = smallest_confirmable_um(np.eye(3) * 0.5**2, 0.9)
    assert r == pytest.approx(0.5 * np.sqrt(scipy.stats.chi2.ppf(0.9, 3)), rel=0.02)
    assert probability_within(np.zeros(3), np.eye(3) * 0.5**2, 0.99 * r) < 0.9


def test_a_loop_that_ends_on_its_cap_says_why_in_words():
    from microcal.procedures.station import Arrival
    from microcal.report.text_tables import arrival_line

    def arrival(status, std_um):
        cov = np.diag(np.square(std_um))
        return Arrival(np.zeros(3), np.zeros(3), np.full(3, 0.1), cov, "closed", status, 6, 480,
                       0.5, 0.9, 6)  # fmt: skip

    noisy = arrival_line(arrival("iterations", [0.2, 0.2, 0.6]))
    assert "stopped at its cap of 6 corrections, not 90 % sure of 0.5 µm" in noisy
    assert "the measurement alone (std up to 0.60 µm) confirms no less than" in noisy
    floor = smallest_confirmable_um(np.diag([0.04, 0.04, 0.36]), 0.9)
    asked = float(noisy.split("--tolerance-um ")[1].split()[0])
    assert floor < asked <= 1.1 * floor + 0.1
    quiet = arrival_line(arrival("iterations", [0.05, 0.05, 0.05]))
    assert "not 90 % sure of 0.5 µm; the error was still shrinking" in quiet
    assert "ended 90 % sure of 0.5 µm" in arrival_line(arrival("tolerance", [0.05] * 3))


def test_the_loop_reaches_the_tolerance_the_open_loop_misses():
    plat, model, measure, _ = _rig(1)
    loop = ClosedLoop(plat.manipulator, model, measure, plat.clock,
                      config=ServoConfig(tolerance_um=0.3, confidence=0.9))  # fmt: skip
    targets = model.p_base_um + np.array(
        [
            [2000.0, 1000.0, 600.0],
            [7000.0, 6000.0, 4000.0],
            [500.0, 7500.0, 2500.0],
            [4000.0, 4000.0, 4500.0],
        ]
    )
    open_err, closed_err = [], []
    for t in targets:
        d_open = np.linalg.solve(model.R, t - model.p_base_um)  # the open loop's joints
        open_err.append(np.linalg.norm(plat.manipulator.truth.position_um(d_open[None])[0] - t))
        loop.move_to_position_um(t)
        closed_err.append(np.linalg.norm(plat.truth_position_um() - t))
    assert min(open_err) > 1.0  # µm: the matrix model alone misses by more than a micrometre
    assert max(closed_err) < 0.6  # µm, worst of the four (tolerance 0.3 at 90 %)
    results = loop.results
    assert all(r.status == "tolerance" for r in results)
    assert all(r.iterations >= 1 for r in results)
    # frames grow as the error shrinks: the last measurement averages more than the first
    assert all(r.steps[-1].frames > r.steps[0].frames for r in results)


def test_a_correction_outside_the_limits_moves_nothing():
    moves = []
    limits = np.array([[0.0, 100.0]] * 3)
    # the tip is measured 5 µm short in x while the joints are at 99: the correction to 104
    # leaves the soft limits
    with pytest.raises(LimitError, match="correction"):
        servo(np.array([104.0, 50.0, 50.0]), np.array([99.0, 50.0, 50.0]), moves.append,
              lambda frames: (np.array([99.0, 50.0, 50.0]), np.eye(3) * 1e-4),
              lambda d: np.eye(3), limits, ServoConfig(tolerance_um=0.1))  # fmt: skip
    assert moves == []
    # and a target outside: the open loop refuses it before anything moves
    plat, model, measure, _ = _rig(2)
    loop = ClosedLoop(plat.manipulator, model, measure, plat.clock)
    before = plat.manipulator.joints_um(plat.clock.now_s())
    with pytest.raises(LimitError):
        loop.move_to_position_um(model.p_base_um + np.array([9400.0, 4000.0, 2000.0]))
    np.testing.assert_array_equal(plat.manipulator.joints_um(plat.clock.now_s()), before)


def test_a_lost_camera_mid_loop_stops_with_the_tip_where_it_was():
    plat, model, measure, state = _rig(3)
    calls = {"n": 0}

    def flaky(d_um, frames):
        calls["n"] += 1
        state["lost"] = calls["n"] >= 2  # the second measurement of the loop fails
        return measure(d_um, frames)

    loop = ClosedLoop(plat.manipulator, model, flaky, plat.clock,
                      config=ServoConfig(tolerance_um=0.05))  # fmt: skip
    with pytest.raises(DetectionError, match="lost the end-effector"):
        loop.move_to_position_um(model.p_base_um + np.array([3000.0, 3000.0, 2000.0]))
    here = plat.manipulator.joints_um(plat.clock.now_s())
    plat.clock.sleep(10.0)
    np.testing.assert_array_equal(plat.manipulator.joints_um(plat.clock.now_s()), here)


def test_a_manipulator_error_mid_loop_propagates_and_the_tip_stays():
    plat, model, measure, _ = _rig(4)
    loop = ClosedLoop(plat.manipulator, model, measure, plat.clock,
                      config=ServoConfig(tolerance_um=0.05))  # fmt: skip

    def failing(d_um):
        raise MoveError("m1: the controller refused the move (test)")

    loop._move_joints = failing  # type: ignore[method-assign]
    with pytest.raises(MoveError):
        loop.move_to_position_um(model.p_base_um + np.array([3000.0, 3000.0, 2000.0]))
    here = plat.manipulator.joints_um(plat.clock.now_s())
    plat.clock.sleep(10.0)
    np.testing.assert_array_equal(plat.manipulator.joints_um(plat.clock.now_s()), here)


def test_a_correction_below_the_resolution_stops_the_loop():
    plat, model, measure, _ = _rig(5)
    loop = ClosedLoop(plat.manipulator, model, measure, plat.clock,
                      config=ServoConfig(tolerance_um=0.01, resolution_um=1000.0))  # fmt: skip
    loop.move_to_position_um(model.p_base_um + np.array([3000.0, 3000.0, 2000.0]))
    assert loop.results[-1].status == "resolution"
    assert loop.results[-1].iterations == 0
