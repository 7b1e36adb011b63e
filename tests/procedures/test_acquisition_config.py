"""AcquisitionConfig refuses settings a run cannot use; the creep wait needs a learned creep."""

from __future__ import annotations

import math

import pytest

from microcal.errors import DeviceError, InputError
from microcal.procedures.acquisition import AcquisitionConfig, CreepEstimator


@pytest.mark.parametrize("settle", ["vision", "fixed"])
def test_the_two_settle_modes_are_accepted(settle):
    assert AcquisitionConfig(settle=settle, fixed_s=0.0).settle == settle


@pytest.mark.parametrize("settle", ["Vision", "fixed:30", "", "none"])
def test_an_unknown_settle_mode_is_refused_naming_expected_and_got(settle):
    with pytest.raises(InputError, match=rf"settle: expected 'vision' or 'fixed', got '{settle}'"):
        AcquisitionConfig(settle=settle)  # type: ignore[arg-type]


@pytest.mark.parametrize("fixed_s", [-1.0, -1e-9, math.nan, math.inf, "30"])
def test_fixed_wait_must_be_finite_and_not_negative(fixed_s):
    with pytest.raises(InputError, match=r"fixed_s: expected a finite number of seconds >= 0"):
        AcquisitionConfig(settle="fixed", fixed_s=fixed_s)


def test_a_zero_or_whole_second_fixed_wait_is_fine():
    assert AcquisitionConfig(settle="fixed", fixed_s=0).fixed_s == 0
    assert AcquisitionConfig(settle="fixed", fixed_s=30).fixed_s == 30


def test_asking_the_creep_wait_before_it_is_learned_is_a_microcal_error():
    creep = CreepEstimator(learn_poses=5)
    assert creep.learning
    with pytest.raises(DeviceError, match=r"creep is not learned yet \(0 of 5 poses watched\)"):
        creep.wait_s(1000.0)


def test_a_chosen_approach_direction_sets_the_side_and_the_limits_still_win():
    import numpy as np

    from microcal.procedures.acquisition import approach_start_um

    limits = np.array([[0.0, 1000.0], [0.0, 1000.0], [0.0, 1000.0]])
    d = np.array([500.0, 500.0, 100.0])
    up_down_up = (1.0, -1.0, 1.0)
    cfg = AcquisitionConfig(approach_um=300.0, approach_seed=4, approach_directions=(up_down_up,))
    # arriving moving up starts below the pose; z cannot start 300 µm below 100: from above
    np.testing.assert_array_equal(approach_start_um(d, 1, cfg, limits), [200.0, 800.0, 400.0])
    given = approach_start_um(d, 7, cfg, limits, np.array([-1.0, -1.0, -1.0]))
    np.testing.assert_array_equal(given, [800.0, 800.0, 400.0])
    # poses beyond the chosen ones, or chosen as NaN, draw their side as before
    drawn = AcquisitionConfig(approach_um=300.0, approach_seed=4)
    for pose in (2, 3):
        np.testing.assert_array_equal(approach_start_um(d, pose, cfg, limits),
                                      approach_start_um(d, pose, drawn, limits))  # fmt: skip
    nan = np.full(3, np.nan)
    np.testing.assert_array_equal(approach_start_um(d, 1, cfg, limits, nan),
                                  approach_start_um(d, 1, drawn, limits))  # fmt: skip
