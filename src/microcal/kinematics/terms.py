"""The term library of the black-box kinematic models (thesis Eq 4.5-4.10).

A term is a product of powers of named inputs: ``dx``, ``dx^2``, ``dx*dy``, ``T^2``, and the
constant ``1``. Inputs are the joint values ``dx, dy, dz`` (µm) and any further measured
variable, such as the temperature ``T`` (°C). A model is linear in its coefficients, so its
design matrix is the terms evaluated at the inputs, and its Jacobian with respect to the
joints follows from the power rule.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import InputError

__all__ = [
    "JOINTS",
    "Term",
    "design_matrix",
    "matrix_terms",
    "parse_term",
    "polynomial_terms",
]

#: The joint inputs of a Cartesian three-axis manipulator, in the thesis's names.
JOINTS: tuple[str, ...] = ("dx", "dy", "dz")

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Term:
    """A monomial: ``powers`` pairs (input name, exponent >= 1); empty for the constant."""

    powers: tuple[tuple[str, int], ...] = ()

    def __post_init__(self) -> None:
        names = [n for n, _ in self.powers]
        if len(set(names)) != len(names):
            raise InputError(f"term: expected each input once, got {names}")
        for name, power in self.powers:
            if not _NAME.match(name) or power < 1:
                raise InputError(
                    f"term: expected input names and exponents >= 1, got {name}^{power}"
                )

    @property
    def name(self) -> str:
        """``1``, ``dx``, ``dx^2``, ``dx*dy`` ... (the inverse of :func:`parse_term`)."""
        if not self.powers:
            return "1"
        return "*".join(n if p == 1 else f"{n}^{p}" for n, p in self.powers)

    @property
    def degree(self) -> int:
        """Total degree (0 for the constant)."""
        return sum(p for _, p in self.powers)

    @property
    def inputs(self) -> tuple[str, ...]:
        """The inputs this term depends on."""
        return tuple(n for n, _ in self.powers)

    def __str__(self) -> str:
        return self.name


def parse_term(text: str) -> Term:
    """Parse a term name: ``"1"``, ``"dx"``, ``"dx^2"``, ``"dx*dz"``, ``"T^2"``.

    Raises
    ------
    InputError
        If the text is not of that form.
    """
    text = text.strip().replace(" ", "")
    if text == "1":
        return Term()
    powers = []
    for factor in text.split("*"):
        name, _, exp = factor.partition("^")
        try:
            power = int(exp) if exp else 1
        except ValueError:
            power = 0
        if not _NAME.match(name) or power < 1:
            raise InputError(
                f"term {text!r}: expected a product of inputs such as 'dx', 'dx^2' or 'dx*dy'"
            )
        powers.append((name, power))
    return Term(tuple(powers))


def matrix_terms(joints: Sequence[str] = JOINTS) -> tuple[Term, ...]:
    """The matrix model's terms (Eq 4.5): each joint, then the constant."""
    return (*(Term(((j, 1),)) for j in joints), Term())


def polynomial_terms(
    joints: Sequence[str] = JOINTS, degree: int = 2, extra: dict[str, int] | None = None
) -> tuple[Term, ...]:
    """The polynomial model's terms (Eq 4.6-4.10), in the thesis's order.

    For three joints and degree 2 this is ``dx, dy, dz, dx^2, dy^2, dz^2, dx*dy, dy*dz,
    dx*dz, 1`` (coefficients a1 ... a10 of Eq 4.7). Higher degrees append their monomials,
    pure powers first. ``extra`` adds powers of further inputs without cross terms, such as
    ``{"T": 2}`` for ``T, T^2`` (Eq 4.10).
    """
    if degree < 1:
        raise InputError(f"degree: expected >= 1, got {degree}")
    k = len(joints)
    terms: list[Term] = [Term(((j, 1),)) for j in joints]
    for deg in range(2, degree + 1):
        pure = [Term(((j, deg),)) for j in joints]
        mixed = []
        for combo in itertools.combinations_with_replacement(range(k), deg):
            if len(set(combo)) == 1:
                continue
            counts = sorted({i: combo.count(i) for i in combo}.items())
            mixed.append((combo, Term(tuple((joints[i], c) for i, c in counts))))
        if deg == 2:
            # The thesis's order for the cross products: neighbours first (dx*dy, dy*dz), then
            # wider gaps (dx*dz).
            mixed.sort(key=lambda item: (item[0][1] - item[0][0], item[0][0]))
        terms += pure + [t for _, t in mixed]
    for name, max_power in (extra or {}).items():
        terms += [Term(((name, p),)) for p in range(1, max_power + 1)]
    terms.append(Term())
    return tuple(terms)


def _columns(
    inputs: ArrayLike, input_names: Sequence[str], terms: Iterable[Term]
) -> tuple[FloatArray, dict[str, int], list[Term]]:
    names = tuple(input_names)
    u = as_array(inputs, "inputs", (None, len(names)))
    index = {n: i for i, n in enumerate(names)}
    term_list = list(terms)
    for t in term_list:
        missing = [n for n in t.inputs if n not in index]
        if missing:
            raise InputError(
                f"term {t.name}: needs input(s) {missing}, but the inputs are {list(names)}"
            )
    return u, index, term_list


def design_matrix(
    inputs: ArrayLike, input_names: Sequence[str], terms: Iterable[Term]
) -> FloatArray:
    """Evaluate terms at inputs.

    Parameters
    ----------
    inputs : (N, k) float
        One column per input, in the order of ``input_names``.
    input_names : sequence of k str
    terms : sequence of m Term

    Returns
    -------
    X : (N, m) float
    """
    u, index, term_list = _columns(inputs, input_names, terms)
    X = np.ones((u.shape[0], len(term_list)))
    for col, t in enumerate(term_list):
        for name, power in t.powers:
            X[:, col] *= u[:, index[name]] ** power
    return X
