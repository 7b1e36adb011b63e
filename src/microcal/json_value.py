"""The type of a value JSON can hold, for the records microcal writes to its files.

A record's ``to_json()`` (or ``to_dict()``) gives ``dict[str, JsonValue]``: an object whose
values are JSON's own (null, booleans, numbers, text, arrays and objects of them), so that it
can be written as it is. Sequences and mappings stand for arrays and objects, so that a
``list[float]`` or a ``dict[str, int]`` is one without a copy. What reads such an object
back narrows each value before it uses it (or validates the whole with a schema).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol, TypeAlias

__all__ = ["JsonRecord", "JsonValue", "checked_json"]

#: A JSON value: null, a boolean, a number, a string, an array or an object of JSON values.
JsonValue: TypeAlias = (
    "bool | int | float | str | Sequence[JsonValue] | Mapping[str, JsonValue] | None"
)


class JsonRecord(Protocol):
    """A typed record that gives the JSON object a file stores of it (a writer takes one
    without knowing its type)."""

    def to_json(self) -> Mapping[str, JsonValue]:
        """The record as a JSON object."""
        ...


def checked_json(value: object, where: str = "value") -> JsonValue:
    """``value`` as a JSON value, checked through: what ``json.dumps`` writes as null,
    booleans, numbers, strings, arrays (lists, tuples) and objects (dicts with string keys).

    Raises
    ------
    TypeError
        A value (or a value inside it, named by its path) that JSON cannot hold.
    """
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, list | tuple):
        return [checked_json(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict):
        out: dict[str, JsonValue] = {}
        for key, v in value.items():
            if not isinstance(key, str):
                raise TypeError(f"{where}: expected text keys, got {key!r}")
            out[key] = checked_json(v, f"{where}.{key}")
        return out
    raise TypeError(f"{where}: {type(value).__name__} is not a JSON value")
