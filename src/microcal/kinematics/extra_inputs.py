"""The registry of a kinematic model's extra inputs: what besides the joints a model may use.

Each entry says, in one place, what an input is called in a model's terms, in
measurements.csv and in the journal, its unit and the degree of its terms. Acquisition
records it from the rig's sensor of that name, measurement carries it to measurements.csv,
identification adds its terms, and compensation asks for its value; none of them names a
particular input. Temperature (thesis Eq 4.10) is the first.

The **approach direction** of each joint (``approach_x``, ``approach_y``, ``approach_z``:
+1 when the joint last moved towards larger values, -1 towards smaller) is recorded by the
acquisition itself, from the moves it commanded, not by a sensor; its terms ``sx, sy, sz``
model reversal error (hysteresis). :data:`EXTRA_GROUPS` names such a set by one name
(``--extra approach``).

To add one (elapsed time...): add an :class:`ExtraInput` here and give the rig a sensor of
that name.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import InputError

__all__ = [
    "APPROACH_INPUTS",
    "EXTRA_GROUPS",
    "EXTRA_INPUTS",
    "ExtraInput",
    "by_symbol",
    "default_extra_inputs",
    "expand_names",
    "extra_input",
    "fixed_approach_values",
    "identifiability_problem",
    "is_approach",
    "values_for",
]


@dataclass(frozen=True)
class ExtraInput:
    """One extra input of a kinematic model.

    Attributes
    ----------
    name : str
        Its name on the command line and in a rig's sensors (``temperature``).
    symbol : str
        Its name in the model's terms (``T``: terms ``T``, ``T^2``).
    column : str
        Its column in measurements.csv and its key in a journal line (``temperature_c``).
    unit : str
        Its unit, as printed.
    degree : int
        The highest power of its polynomial terms.
    meaning : str
        What it is, for help texts and the report.
    """

    name: str
    symbol: str
    column: str
    unit: str
    degree: int
    meaning: str


EXTRA_INPUTS: dict[str, ExtraInput] = {
    "temperature": ExtraInput(
        "temperature", "T", "temperature_c", "°C", 2, "ambient temperature (thesis Eq 4.10)"
    ),
    **{
        f"approach_{axis}": ExtraInput(
            f"approach_{axis}",
            f"s{axis}",
            f"approach_{axis}",
            "±1",
            1,
            f"direction joint {axis} last moved in (+1 up, -1 down)",
        )
        for axis in "xyz"
    },
}

#: The approach directions of the three joints, in joint order.
APPROACH_INPUTS: tuple[str, ...] = ("approach_x", "approach_y", "approach_z")

#: Names that stand for several inputs at once.
EXTRA_GROUPS: dict[str, tuple[str, ...]] = {"approach": APPROACH_INPUTS}


def expand_names(names: Sequence[str]) -> list[str]:
    """Registry names with each group (``approach``) replaced by its members, in order, once
    each; InputError for an unknown name."""
    out: list[str] = []
    for name in names:
        for member in EXTRA_GROUPS.get(name, (name,)):
            extra_input(member)
            if member not in out:
                out.append(member)
    return out


def is_approach(name: str) -> bool:
    """Whether the input is a joint's approach direction (recorded by acquisition itself)."""
    return name in APPROACH_INPUTS


def fixed_approach_values(symbols: Sequence[str]) -> dict[str, float]:
    """The model's approach-direction inputs by registry name, each +1: every joint arriving
    moving up, as a fixed approach from below makes it (empty for a model without them)."""
    names = [by_symbol(s).name for s in symbols]
    return {name: 1.0 for name in names if is_approach(name)}


def extra_input(name: str) -> ExtraInput:
    """The registry's entry of that name; InputError naming the known ones otherwise."""
    try:
        return EXTRA_INPUTS[name]
    except KeyError:
        raise InputError(
            f"extra input: expected one of {sorted(EXTRA_INPUTS)} or {sorted(EXTRA_GROUPS)}, "
            f"got {name!r}"
        ) from None


def by_symbol(symbol: str) -> ExtraInput:
    """The registry's entry whose term symbol is ``symbol`` (a model's input name)."""
    for entry in EXTRA_INPUTS.values():
        if entry.symbol == symbol:
            return entry
    raise InputError(
        f"extra input: the model's input {symbol!r} is not one microcal knows "
        f"({[e.symbol for e in EXTRA_INPUTS.values()]})"
    )


def values_for(symbols: Sequence[str], values: Mapping[str, float]) -> FloatArray | None:
    """The values of a model's extra inputs in the model's order, (1, e); None for none.

    Parameters
    ----------
    symbols : sequence of str
        The model's extra inputs (``KinematicModel.extra_inputs``).
    values : mapping of name -> value
        Values by registry name (``{"temperature": 23.1}``).

    Raises
    ------
    InputError
        A value the model needs and ``values`` lacks, naming the option that gives it.
    """
    if not symbols:
        return None
    out = []
    for symbol in symbols:
        entry = by_symbol(symbol)
        if entry.name not in values:
            raise InputError(
                f"the model needs the {entry.meaning} ({entry.unit}); give --{entry.name}"
            )
        out.append(float(values[entry.name]))
    return np.array([out])


def default_extra_inputs(symbols: Sequence[str]) -> FloatArray:
    """The values a model's extra inputs take when none are given, (e,): each approach
    direction +1 (every joint arriving moving up, as a fixed approach from below makes it).

    Raises
    ------
    InputError
        An input without a default (the temperature), naming each input the model needs in
        its order, with its meaning and unit.
    """
    entries = [by_symbol(s) for s in symbols]
    if all(is_approach(e.name) for e in entries):
        return np.ones(len(entries))
    needs = ", ".join(f"{e.symbol} ({e.meaning}, {e.unit})" for e in entries)
    raise InputError(
        f"extra: this model also needs {needs}; give one value per input in that order "
        "(an approach direction is +1 when the joint arrives moving up)"
    )


#: An extra input explained this well (R^2) by a quadratic in the joints cannot be told apart
#: from the joints' own terms.
MAX_R2_WITH_JOINTS = 0.98


def identifiability_problem(name: str, values: FloatArray, d_um: FloatArray) -> str | None:
    """Why an extra input's effect cannot be identified from these poses, or None.

    An approach direction must take each sign in at least max(3, 5 %) of the poses; any
    input must not follow the joints (R^2 of a quadratic in them at most
    :data:`MAX_R2_WITH_JOINTS`), or its effect and theirs cannot be told apart.

    Parameters
    ----------
    name : str
        Registry name.
    values : (N,) float
    d_um : (N, k) float
        The joints that move.
    """
    v = np.asarray(values, dtype=np.float64)
    n = v.size
    if is_approach(name):
        fewest = int(min(np.sum(v > 0), np.sum(v < 0)))
        need = max(3, int(np.ceil(0.05 * n)))
        if fewest < need:
            return (
                f"{name} takes one of its signs in only {fewest} of {n} poses (at least {need} "
                "needed): approach each pose from a random side (approach_um)"
            )
    d = np.asarray(d_um, dtype=np.float64)
    span = np.ptp(d, axis=0)
    z = (d - d.min(axis=0)) / np.where(span > 0, span, 1.0)
    k = z.shape[1]
    cols = [np.ones(n), *z.T, *(z[:, i] * z[:, j] for i in range(k) for j in range(i, k))]
    X = np.column_stack(cols)
    centred = v - v.mean()
    total = float(centred @ centred)
    if total == 0.0:
        return f"{name} has the same value in every pose: its effect cannot be identified"
    fit, *_ = np.linalg.lstsq(X, v, rcond=None)
    r2 = 1.0 - float(np.sum((v - X @ fit) ** 2)) / total
    if r2 > MAX_R2_WITH_JOINTS:
        fix = (
            "approach each pose from a random side (approach_um)"
            if is_approach(name)
            else "acquire the poses in a random order so it varies apart from them"
        )
        return (
            f"{name} follows the joints' positions (R^2 {r2:.3f} > {MAX_R2_WITH_JOINTS}): its "
            f"effect cannot be told from theirs; {fix}"
        )
    return None
