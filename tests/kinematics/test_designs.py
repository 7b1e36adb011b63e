"""Designs of an acquisition (thesis 4.2): reproducible, identifying, inside the soft limits."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import DegenerateDataError, LimitError
from microcal.kinematics.designs import check_design, make_design

LIMITS = np.array([[-500, 8500], [-500, 8500], [-500, 5300.0]])
LOW, HIGH = [0, 0, 0], [8000, 8000, 4800]


@pytest.mark.parametrize("kind", ["random", "sobol", "lhs", "grid"])
def test_designs_are_reproducible_and_identifiable(kind):
    a = make_design(kind, 170, LOW, HIGH, seed=3)
    b = make_design(kind, 170, LOW, HIGH, seed=3)
    np.testing.assert_array_equal(a, b)
    assert np.all(a >= LOW)
    assert np.all(a <= HIGH)
    check_design(a, LIMITS)


def test_designs_that_cannot_identify_are_refused():
    d = make_design("random", 50, LOW, HIGH, seed=1)
    one_axis = d.copy()
    one_axis[:, 2] = 100.0
    with pytest.raises(DegenerateDataError, match="moves axis z over 0 % of its travel"):
        check_design(one_axis, LIMITS)
    together = d.copy()
    together[:, 1] = together[:, 0]
    with pytest.raises(DegenerateDataError, match="moves axes x and y together"):
        check_design(together, LIMITS)
    outside = d.copy()
    outside[7, 0] = 9000.0
    with pytest.raises(
        LimitError, match=r"command 8: axis x = 9000\.000 µm is outside the soft limits"
    ):
        check_design(outside, LIMITS)
