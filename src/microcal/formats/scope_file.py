"""The scope file (``microcal.scope/1``): a microscope camera's calibration, one set per objective.

``microcal scope-calibrate --objective 40x --out scope.json`` adds (or replaces) the set
named ``40x``; a later run with ``--objective 10x`` adds its own set beside it and leaves the
others as they were. A command that uses the file names the set it wants
(:func:`load_objective`); a name the file does not hold is refused in one line naming the
ones it does. The file is read, changed and replaced under its lock
(:func:`~microcal.formats.file_lock.locked_update`) and written atomically, so two
objectives calibrated at once both land and a crash leaves the old file whole.

The keys of one objective's set are listed in ``docs/formats.md``; more keys may be added.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from pathlib import Path

from pydantic import Field
from pydantic import JsonValue as AnyJson

from .._validation import excerpt
from ..errors import InputError
from ..json_value import JsonValue
from .atomic import write_text_atomic
from .file_lock import locked_update
from .json_file import FileSchema, parse_schema, read_versioned_json

__all__ = [
    "SCOPE_FORMAT",
    "SCOPE_FORMATS",
    "ObjectiveSet",
    "check_objective_name",
    "load_objective",
    "objective_names",
    "write_objective",
]

SCOPE_FORMAT = "microcal.scope/1"
SCOPE_FORMATS = (SCOPE_FORMAT,)  # the versions this microcal reads

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,39}$")


class ObjectiveSet(FileSchema):
    """One objective's calibration (the keys other tools read; the rest is kept as is)."""

    pixel_size_affine: list[float] = Field(min_length=6, max_length=6)
    pixel_size_um: float = Field(gt=0)
    rotation_deg: float
    distortion: dict[str, AnyJson]
    focus: dict[str, AnyJson]


class _ScopeSchema(FileSchema):
    format: str
    objectives: dict[str, ObjectiveSet]
    provenance: dict[str, AnyJson] = Field(default_factory=dict)


def check_objective_name(name: str) -> str:
    """``name`` if it is an objective's name (letters, digits, ``. _ + -``, up to 40, e.g.
    ``40x`` or ``10x-air``); InputError naming the rule otherwise."""
    if not isinstance(name, str) or not _NAME.match(name):
        raise InputError(
            f"--objective {excerpt(name)}: expected a name of letters, digits and . _ + - "
            "(up to 40, e.g. 40x or 10x-air)"
        )
    return name


def _read(path: Path) -> _ScopeSchema:
    raw = read_versioned_json(path, SCOPE_FORMATS, link_ok=True)
    return parse_schema(_ScopeSchema, raw, path)


def objective_names(path: str | os.PathLike[str]) -> list[str]:
    """The objectives a scope file holds, sorted."""
    return sorted(_read(Path(path)).objectives)


def load_objective(path: str | os.PathLike[str], name: str) -> dict[str, JsonValue]:
    """One objective's set, as its JSON object.

    Raises
    ------
    InputError
        The file holds no set of that name: ``objective '20x' is not in scope.json; it
        holds 10x, 40x``.
    FormatError
        No such file, not a scope file, or a malformed set (the key named).
    """
    p = Path(path)
    sets = _read(p).objectives
    if name not in sets:
        held = ", ".join(sorted(sets)) or "none"
        raise InputError(
            f"objective {excerpt(name)} is not in {p}; it holds {held} "
            "(calibrate it with microcal scope-calibrate --objective NAME)"
        )
    out: dict[str, JsonValue] = sets[name].model_dump(mode="json")
    return out


def write_objective(
    path: str | os.PathLike[str],
    name: str,
    record: Mapping[str, JsonValue],
    provenance: Mapping[str, JsonValue] | None = None,
) -> Path:
    """Add (or replace) objective ``name``'s set in the scope file ``path``; the other sets
    stay as they were.

    Read, changed and written under the file's lock, atomically; a new file is made.

    Parameters
    ----------
    record : mapping
        The set's JSON object (``ScopeCalibration.to_json()`` and what the workflow adds).
    provenance : mapping, optional
        Stored in the set as its ``provenance``.

    Raises
    ------
    InputError
        A bad objective name (nothing written).
    FormatError
        An existing file that is not a scope file this microcal reads (nothing written).
    """
    check_objective_name(name)
    entry = dict(record)
    if provenance is not None:
        entry["provenance"] = dict(provenance)
    parse_schema(ObjectiveSet, entry, f"objective {name}")  # refuse before the file is touched
    p = Path(path)
    with locked_update(p):
        if p.exists():
            raw = read_versioned_json(p, SCOPE_FORMATS, link_ok=True)
            parse_schema(_ScopeSchema, raw, p)
        else:
            raw = {"format": SCOPE_FORMAT, "objectives": {}}
        objectives = raw.get("objectives")
        assert isinstance(objectives, dict)  # checked by the schema
        objectives[name] = entry
        raw["objectives"] = dict(sorted(objectives.items()))
        write_text_atomic(p, json.dumps(raw, indent=2, allow_nan=False) + "\n")
    return p
