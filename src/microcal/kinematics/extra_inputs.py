"""The registry of a kinematic model's extra inputs: what besides the joints a model may use.

Each entry says, in one place, what an input is called in a model's terms, in
measurements.csv and in the journal, its unit and the degree of its terms. Acquisition
records it from the rig's sensor of that name, measurement carries it to measurements.csv,
identification adds its terms, and compensation asks for its value; none of them names a
particular input. Temperature (thesis Eq 4.10) is the first.

To add one (approach direction, elapsed time...): add an :class:`ExtraInput` here and give
the rig a sensor of that name.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import InputError

__all__ = ["EXTRA_INPUTS", "ExtraInput", "by_symbol", "extra_input", "values_for"]


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
}


def extra_input(name: str) -> ExtraInput:
    """The registry's entry of that name; InputError naming the known ones otherwise."""
    try:
        return EXTRA_INPUTS[name]
    except KeyError:
        raise InputError(
            f"extra input: expected one of {sorted(EXTRA_INPUTS)}, got {name!r}"
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
