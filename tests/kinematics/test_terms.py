"""The term library (Eq 4.5-4.10): names, order, evaluation and derivatives."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import InputError
from microcal.kinematics import (
    JOINTS,
    Term,
    design_matrix,
    matrix_terms,
    parse_term,
    polynomial_terms,
)


def test_thesis_polynomial_terms_in_the_thesis_order():
    # Eq 4.7: a1 dx + a2 dy + a3 dz + a4 dx² + a5 dy² + a6 dz² + a7 dx dy + a8 dy dz + a9 dx dz + a10
    names = [t.name for t in polynomial_terms()]
    assert names == ["dx", "dy", "dz", "dx^2", "dy^2", "dz^2", "dx*dy", "dy*dz", "dx*dz", "1"]
    assert [t.name for t in matrix_terms()] == ["dx", "dy", "dz", "1"]


def test_extra_inputs_and_higher_degree():
    names = [t.name for t in polynomial_terms(JOINTS, 2, {"T": 2})]
    assert names[-3:] == ["T", "T^2", "1"]  # Eq 4.10
    cubic = polynomial_terms(JOINTS, 3)
    assert len(cubic) == 3 + 6 + 10 + 1  # monomials of degree 1, 2, 3 in 3 variables, constant
    assert len({t.name for t in cubic}) == len(cubic)


@pytest.mark.parametrize("name", ["1", "dx", "dx^2", "dx*dy", "dx^2*dz", "T^2", "temp_c"])
def test_parse_round_trip(name):
    assert parse_term(name).name == name


@pytest.mark.parametrize("bad", ["", "dx^0", "dx^a", "2dx", "dx**2", "dx*dx"])
def test_parse_rejects_bad_terms(bad):
    with pytest.raises(InputError):
        parse_term(bad)


def test_design_matrix_values():
    u = np.array([[2.0, 3.0, 5.0], [-1.0, 0.5, 4.0]])
    X = design_matrix(u, JOINTS, polynomial_terms())
    expected = [[2, 3, 5, 4, 9, 25, 6, 15, 10, 1], [-1, 0.5, 4, 1, 0.25, 16, -0.5, 2, -4, 1]]
    np.testing.assert_array_equal(X, expected)


def test_missing_input_is_named():
    with pytest.raises(InputError, match=r"term T: needs input\(s\) \['T'\]"):
        design_matrix(np.zeros((2, 3)), JOINTS, [Term((("T", 1),))])
