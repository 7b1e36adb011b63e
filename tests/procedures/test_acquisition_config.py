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
