"""The term library of the black-box kinematic models (thesis Eq 4.5-4.10, and beyond).

A term is a product of powers of named inputs: ``dx``, ``dx^2``, ``dx*dy``, ``T^2``, ``sx*dx``
and the constant ``1``. Inputs are the joint values ``dx, dy, dz`` (µm) and any further
measured variable, such as the temperature ``T`` (°C) or a joint's approach direction ``sx``
(±1). A term may also carry **wave factors** along one input, the half-range cosine basis of
an interval: ``cos3[dx:0:8000]`` is ``cos(3 pi (dx - 0) / (8000 - 0))``. Over the interval
these follow any smooth error profile of one joint (guideway straightness, angular errors
seen at the tool through an Abbe offset) that no low-order polynomial does, without the
jump at the ends a periodic Fourier series has. A model is linear in its coefficients, so
its design matrix is the terms evaluated at the inputs, and its Jacobian with respect to
the joints follows from the power rule and the derivatives of the waves (``cos`` turns into
``sin`` and back).
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
    "Wave",
    "design_matrix",
    "design_matrix_derivative",
    "matrix_terms",
    "parse_term",
    "polynomial_terms",
    "terms_without",
    "wave_terms",
]

#: The joint inputs of a Cartesian three-axis manipulator, in the thesis's names.
JOINTS: tuple[str, ...] = ("dx", "dy", "dz")

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_WAVE = re.compile(r"^(cos|sin)([1-9][0-9]*)\[([A-Za-z_][A-Za-z0-9_]*):([^:\]]+):([^:\]]+)\]$")


@dataclass(frozen=True)
class Wave:
    """A wave factor along one input: ``func(harmonic * pi * (u - low) / (high - low))``.

    ``func`` is ``"cos"`` (the half-range cosine basis of ``[low, high]``) or ``"sin"`` (what
    a cosine's derivative holds). Named ``cos3[dx:0:8000]``.
    """

    input: str
    func: str
    harmonic: int
    low: float
    high: float

    def __post_init__(self) -> None:
        if not _NAME.match(self.input) or self.func not in ("cos", "sin"):
            raise InputError(f"wave: expected cos or sin of an input name, got {self.name}")
        if self.harmonic < 1:
            raise InputError(f"wave {self.name}: expected a harmonic >= 1")
        if not (np.isfinite(self.low) and np.isfinite(self.high) and self.high > self.low):
            raise InputError(f"wave {self.name}: expected finite low < high")

    @property
    def name(self) -> str:
        """``cos3[dx:0:8000]``."""
        return f"{self.func}{self.harmonic}[{self.input}:{self.low:.12g}:{self.high:.12g}]"

    @property
    def omega(self) -> float:
        """Angular rate per unit of the input, rad per unit."""
        return self.harmonic * np.pi / (self.high - self.low)

    def value(self, u: FloatArray) -> FloatArray:
        """The factor at ``u`` (N,)."""
        phase = self.omega * (u - self.low)
        out: FloatArray = np.cos(phase) if self.func == "cos" else np.sin(phase)
        return out

    def derivative(self) -> tuple[float, Wave]:
        """``(c, w)`` with ``d value / du = c * w.value``."""
        if self.func == "cos":
            return -self.omega, Wave(self.input, "sin", self.harmonic, self.low, self.high)
        return self.omega, Wave(self.input, "cos", self.harmonic, self.low, self.high)


@dataclass(frozen=True)
class Term:
    """A product: ``powers`` pairs (input name, exponent >= 1) and ``waves`` (wave factors,
    each on an input of its own); both empty for the constant."""

    powers: tuple[tuple[str, int], ...] = ()
    waves: tuple[Wave, ...] = ()

    def __post_init__(self) -> None:
        names = [n for n, _ in self.powers] + [w.input for w in self.waves]
        if len(set(names)) != len(names):
            raise InputError(f"term: expected each input once, got {names}")
        for name, power in self.powers:
            if not _NAME.match(name) or power < 1:
                raise InputError(
                    f"term: expected input names and exponents >= 1, got {name}^{power}"
                )

    @property
    def name(self) -> str:
        """``1``, ``dx``, ``dx^2``, ``dx*dy``, ``cos2[dx:0:8000]*sx`` ... (the inverse of
        :func:`parse_term`)."""
        if not self.powers and not self.waves:
            return "1"
        parts = [w.name for w in self.waves]
        parts += [n if p == 1 else f"{n}^{p}" for n, p in self.powers]
        return "*".join(parts)

    @property
    def degree(self) -> int:
        """Total degree of the powers (0 for the constant); a wave factor counts one."""
        return sum(p for _, p in self.powers) + len(self.waves)

    @property
    def is_monomial(self) -> bool:
        """Whether the term is a product of powers only (no wave factor)."""
        return not self.waves

    @property
    def inputs(self) -> tuple[str, ...]:
        """The inputs this term depends on."""
        return tuple(w.input for w in self.waves) + tuple(n for n, _ in self.powers)

    def value(self, u: FloatArray, index: dict[str, int]) -> FloatArray:
        """The term at inputs ``u`` (N, k) whose columns ``index`` names; (N,)."""
        out = np.ones(u.shape[0])
        for name, power in self.powers:
            out *= u[:, index[name]] ** power
        for w in self.waves:
            out *= w.value(u[:, index[w.input]])
        return out

    def derivative(self, wrt: str) -> list[tuple[float, Term]]:
        """``d term / d wrt`` as a sum of ``coefficient * term``; empty when it is zero."""
        out: list[tuple[float, Term]] = []
        for i, (name, power) in enumerate(self.powers):
            if name == wrt:
                lowered = list(self.powers)
                if power == 1:
                    del lowered[i]
                else:
                    lowered[i] = (name, power - 1)
                out.append((float(power), Term(tuple(lowered), self.waves)))
        for i, w in enumerate(self.waves):
            if w.input == wrt:
                c, dw = w.derivative()
                waves = list(self.waves)
                waves[i] = dw
                out.append((c, Term(self.powers, tuple(waves))))
        return out

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
    waves = []
    for factor in text.split("*"):
        wave = _WAVE.match(factor)
        if wave:
            try:
                low, high = float(wave.group(4)), float(wave.group(5))
            except ValueError:
                low = high = float("nan")
            waves.append(Wave(wave.group(3), wave.group(1), int(wave.group(2)), low, high))
            continue
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
    return Term(tuple(powers), tuple(waves))


def terms_without(terms: Iterable[Term], inputs: Iterable[str]) -> tuple[Term, ...]:
    """The terms that use none of ``inputs`` (a held joint's terms left out)."""
    left_out = set(inputs)
    return tuple(t for t in terms if not left_out & set(t.inputs))


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


def wave_terms(
    joints: Sequence[str], low: Sequence[float], high: Sequence[float], harmonics: int
) -> tuple[Term, ...]:
    """Half-range cosine terms along each joint: ``cos1 ... cos<harmonics>`` of its interval.

    Parameters
    ----------
    joints : sequence of j str
    low, high : sequence of j float
        Each joint's interval (the travel the model is identified on).
    harmonics : int
        The highest harmonic, >= 1.
    """
    if harmonics < 1:
        raise InputError(f"harmonics: expected >= 1, got {harmonics}")
    return tuple(
        Term((), (Wave(j, "cos", k, float(lo), float(hi)),))
        for k in range(1, harmonics + 1)
        for j, lo, hi in zip(joints, low, high, strict=True)
    )


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
        X[:, col] = t.value(u, index)
    return X


def design_matrix_derivative(
    inputs: ArrayLike, input_names: Sequence[str], terms: Iterable[Term], wrt: str
) -> FloatArray:
    """Derivative of :func:`design_matrix` with respect to one input.

    Returns
    -------
    dX : (N, m) float
        ``dX[n, a] = d term_a / d wrt`` at sample n.
    """
    u, index, term_list = _columns(inputs, input_names, terms)
    dX = np.zeros((u.shape[0], len(term_list)))
    for col, t in enumerate(term_list):
        for c, d in t.derivative(wrt):
            dX[:, col] += c * d.value(u, index)
    return dX
