"""Reversal error: the joints' approach directions as extra inputs, recorded, fitted,
compensated with a fixed approach, and ISO 9283's multi-directional variation (vAP)."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import InputError, LimitError, sim
from microcal.control.feedforward import APPROACH_UM, FeedForward, extra_inputs_reader
from microcal.kinematics.designs import make_design
from microcal.kinematics.extra_inputs import APPROACH_INPUTS, default_extra_inputs, expand_names
from microcal.metrics import multi_directional_variation
from microcal.procedures.acquisition import AcquisitionConfig, acquire, approach_start_um
from microcal.procedures.evaluation import approach_detours_um, run_multi_directional
from microcal.procedures.identification import calibrate_manipulator
from microcal.sim.kinematics import approach_signs
from microcal.thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM


def test_the_group_name_stands_for_the_three_joints_once_each():
    assert expand_names(["approach"]) == list(APPROACH_INPUTS)
    assert expand_names(["temperature", "approach_y", "approach"]) == [
        "temperature",
        "approach_y",
        "approach_x",
        "approach_z",
    ]
    with pytest.raises(InputError, match=r"or \['approach'\], got 'backlash'"):
        expand_names(["backlash"])


def test_vap_of_a_hand_computed_example():
    # ISO 9283 7.3: barycentres (1, 0, 0), (0, 2, 0), (0, 0, 0): the largest gap is
    # |(1, 0, 0) - (0, 2, 0)| = sqrt(5).
    by_direction = [
        [[0.5, 0, 0], [1.5, 0, 0]],
        [[0, 1, 0], [0, 3, 0], [0, 2, 0]],
        [[0, 0, 0]],
    ]
    assert multi_directional_variation(by_direction) == pytest.approx(np.sqrt(5.0), abs=1e-12)
    with pytest.raises(InputError, match="two or more approach directions"):
        multi_directional_variation([[[0, 0, 0]]])


def _journal(approach_um, poses=8):
    plat = sim.platform("thesis", seed=3)
    d = make_design("random", poses, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM, seed=4)
    records = []
    cfg = AcquisitionConfig(settle="fixed", fixed_s=0.5, frames_per_pose=1,
                            approach_um=approach_um, approach_seed=9)  # fmt: skip
    acquire(plat.manipulator, plat.cameras, plat.clock, d, list(range(1, poses + 1)),
            plat.scene.board, lambda p, f, r: records.append(r), config=cfg)  # fmt: skip
    signs = np.array([[r.approach[n] for n in APPROACH_INPUTS] for r in records])
    return plat, d, cfg, signs


def test_acquisition_records_the_direction_each_joint_last_moved_in():
    _, d, _, signs = _journal(0.0)
    # Straight from pose to pose: the signs of the steps (the run starts at zero joints).
    np.testing.assert_array_equal(signs, approach_signs(d))


@pytest.mark.slow
def test_a_random_approach_is_recorded_and_repeats_on_resume():
    plat, d, cfg, signs = _journal(150.0)
    for k, row in enumerate(d):
        start = approach_start_um(row, k + 1, cfg, plat.manipulator.limits_um)
        np.testing.assert_allclose(np.abs(start - row), 150.0, atol=1e-9)
        np.testing.assert_array_equal(signs[k], np.sign(row - start))
    assert plat.manipulator._signs.tolist() == signs[-1].tolist()  # what the device did
    # The sides are drawn apart from the positions: both directions occur on every joint.
    assert np.all((signs == 1).any(axis=0))
    assert np.all((signs == -1).any(axis=0))
    _, _, _, again = _journal(150.0)
    np.testing.assert_array_equal(again, signs)


def _truth_fit(plat, n=170, seed=5):
    """The polynomial model with direction terms, fitted to true positions (no cameras)."""
    truth = plat.manipulator.truth
    d = make_design("random", n, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM, seed=seed)
    s = np.random.default_rng(seed).choice([-1.0, 1.0], (n, 3))
    p = truth.position_um(d, s) + np.random.default_rng(seed + 1).normal(0, 0.3, (n, 3))
    extra = dict(zip(APPROACH_INPUTS, s.T, strict=True))
    cal, fits = calibrate_manipulator("m1", d, p, "polynomial", extra_inputs=extra)
    return cal, fits


def test_identification_finds_the_reversal_error():
    plat = sim.platform("thesis", seed=0)
    cal, _ = _truth_fit(plat)
    model = cal.model
    assert set(model.extra_inputs) == {"sx", "sy", "sz"}
    h = plat.manipulator.truth.hysteresis_um
    # Metric: each axis's own direction coefficient against the true half-gap, µm (noise
    # 0.3 µm over 170 poses: standard error about 0.03 µm).
    for axis, symbol in enumerate(("sx", "sy", "sz")):
        got = {name: c for name, c, _ in model.axis_terms(axis)}
        assert got.get(symbol, 0.0) == pytest.approx(h[axis], abs=0.1), (axis, got)


def test_left_out_the_approach_directions_are_the_fixed_approach_from_below():
    plat = sim.platform("thesis", seed=0)
    cal, _ = _truth_fit(plat)
    targets = cal.predict_um(np.array([[4000.0, 4000.0, 2400.0], [1500.0, 6500.0, 900.0]]))
    # Metric: joints, µm; the defaults are the explicit +1 exactly (same solve).
    np.testing.assert_allclose(cal.joints_for(targets), cal.joints_for(targets, extra=[1, 1, 1]),
                               rtol=0, atol=1e-9)  # fmt: skip
    d = cal.joints_for(targets)
    np.testing.assert_allclose(cal.predict_um(d), targets, rtol=0, atol=1e-6)
    np.testing.assert_allclose(cal.predict_um(d), cal.predict_um(np.hstack([d, np.ones((2, 3))])),
                               rtol=0, atol=1e-12)  # fmt: skip
    assert default_extra_inputs(("sx", "sy", "sz")).tolist() == [1.0, 1.0, 1.0]
    with pytest.raises(InputError, match=r"needs T \(ambient temperature .*\), sx \(direction"):
        default_extra_inputs(("T", "sx"))


def test_a_model_with_direction_terms_arrives_moving_up_and_is_refused_near_the_floor():
    plat = sim.platform("thesis", seed=0)
    cal, _ = _truth_fit(plat)
    with pytest.raises(InputError, match="needs the clock"):
        FeedForward(plat.manipulator, cal.model, "optimal")
    ff = FeedForward(plat.manipulator, cal.model, "optimal",
                     extra_inputs_reader(cal.model, {}), plat.clock)  # fmt: skip
    plat.manipulator.move_to_um([6000.0, 6000.0, 4000.0])  # from above
    plat.manipulator.wait_until_stopped(plat.clock)
    d = ff.move_to_position_um(
        cal.model.predict_um(np.array([[3000.0, 2000.0, 1000.0, 1, 1, 1]]))[0]
    )
    plat.manipulator.wait_until_stopped(plat.clock)
    assert plat.manipulator._signs.tolist() == [1.0, 1.0, 1.0]
    np.testing.assert_allclose(d, [3000.0, 2000.0, 1000.0], atol=1e-6)
    low = plat.manipulator.limits_um[:, 0]
    target = cal.model.predict_um(np.array([[*(low + APPROACH_UM / 2), 1, 1, 1]]))[0]
    before = plat.manipulator.joints_um(plat.clock.now_s())
    with pytest.raises(LimitError, match="arrive moving up"):
        ff.move_to_position_um(target)
    np.testing.assert_array_equal(plat.manipulator.joints_um(plat.clock.now_s()), before)


def test_detours_stay_inside_the_travel():
    low, high = np.zeros(3), np.array([8000.0, 8000.0, 4800.0])
    out = approach_detours_um(np.array([8000.0, 0.0, 300.0]), low, high)
    # From below, above and mixed; a side outside the travel is the other one.
    np.testing.assert_allclose(out, [[7700, 300, 0], [7700, 300, 600], [7700, 300, 600]])
    with pytest.raises(InputError, match="no room"):
        approach_detours_um(np.array([100.0, 0.0, 0.0]), low, np.array([200.0, 200.0, 200.0]))


def test_vap_by_truth_falls_with_direction_terms():
    plat = sim.platform("thesis", seed=0)
    cal, fits = _truth_fit(plat)
    plain, _ = calibrate_manipulator("m1", fits["polynomial"].inputs[:, :3],
                                     fits["polynomial"].positions_um, "polynomial")  # fmt: skip
    conditions = {
        "uncalibrated": None,
        "plain": FeedForward(plat.manipulator, plain.model, "optimal"),
        "direction": FeedForward(plat.manipulator, cal.model, "optimal",
                                 extra_inputs_reader(cal.model, {}), plat.clock),
    }  # fmt: skip
    out = run_multi_directional(plat.manipulator, plat.clock, None, conditions, cycles=2,
                                settle_s=5.0, truth=plat.truth_position_um)["truth"]  # fmt: skip
    h = np.linalg.norm(plat.manipulator.truth.hysteresis_um)
    # Metric: mean vAP over the Table 5-2 poses, µm, against the reversal error's size.
    assert out["plain"].vap_um > 0.8 * h
    assert out["direction"].vap_um < 0.3
    assert out["direction"].max_vap_um >= out["direction"].vap_um
    assert len(out["direction"].poses) == 8


def test_solving_one_position_assumes_the_fixed_approach_and_says_so():
    from microcal.procedures.compensation import solve_position
    from microcal.report.text_tables import solution_lines

    plat = sim.platform("thesis", seed=0)
    cal, _ = _truth_fit(plat)
    target = cal.model.predict_um(np.array([[3000.0, 2000.0, 1000.0, 1, 1, 1]]))[0]
    sol = solve_position(cal, target)
    assert sol.approach_from_below
    np.testing.assert_allclose(sol.d_um, [3000.0, 2000.0, 1000.0], atol=1e-6)
    assert any("moving up" in line for line in solution_lines(sol, cal))
