"""``results.json``: the figures of evaluation runs (and of the demo), merged as they come.

Its schema is :class:`~microcal.formats.records.Results`: every section optional, any other
key kept. NaN is written as null (JSON has no NaN).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..json_value import JsonRecord, JsonValue
from .atomic import write_text_atomic
from .file_lock import locked_update
from .json_file import parse_schema, read_versioned_json
from .records import RESULTS_FORMAT, RESULTS_FORMATS, DecouplingResult, DeviceResults, Results

__all__ = [
    "RESULTS_FORMAT",
    "Results",
    "load_results",
    "read_results",
    "shape_problem",
    "update_results",
]


def _plain(value: object) -> JsonValue:
    """``value`` as JSON values: numpy arrays and numbers as lists and numbers, NaN and
    infinity as null (JSON has neither), keys as text."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.floating | float):
        f = float(value)
        return f if np.isfinite(f) else None
    if isinstance(value, np.integer):
        return int(value)
    if value is None or isinstance(value, str | int):
        return value
    raise TypeError(f"results: {type(value).__name__} is not a JSON value")


def _plain_object(value: Mapping[str, object]) -> dict[str, JsonValue]:
    return {str(k): _plain(v) for k, v in value.items()}


def read_results(path: str | os.PathLike[str], *, link_ok: bool = True) -> Results:
    """Read and validate results.json as a typed document.

    ``link_ok``: ``path`` may be a symbolic link to the file (one the user named); False for
    a file a run directory holds (:mod:`.safe_open`).

    Raises
    ------
    FormatError
        Missing file, not JSON, an unknown format version, a section of the wrong shape or a
        figure of the wrong size (:func:`shape_problem`); the message names the key.
    """
    raw = read_versioned_json(path, RESULTS_FORMATS, link_ok=link_ok)
    results = parse_schema(Results, raw, Path(path))
    problem = shape_problem(results)
    if problem is not None:
        raise FormatError(f"{path}: {problem}")
    return results


def shape_problem(results: DeviceResults) -> str | None:
    """The first figure of ``results`` whose shape is not the one microcal writes, as
    ``key.path: what was expected``, or None.

    The schema types each value; this checks what it cannot: a pose's AP has x, y and z, a
    decoupling run's ranges and Ω name each axis, its samples are (x, y, z) rows with the
    moving axis of each. A station's devices are checked as well.
    """
    for source, by_condition in (results.pose_accuracy or {}).items():
        for condition, pa in by_condition.items():
            for k, pose in enumerate(pa.poses):
                if len(pose.ap_um) != 3:
                    return (f"pose_accuracy.{source}.{condition}.poses.{k}.ap_um: expected 3 "
                            f"values (x, y, z), got {len(pose.ap_um)}")  # fmt: skip
    for source, runs in (results.decoupling or {}).items():
        for condition, dc in runs.items():
            problem = _decoupling_problem(dc)
            if problem is not None:
                return f"decoupling.{source}.{condition}.{problem}"
    if isinstance(results, Results):
        for name, device in (results.devices or {}).items():
            problem = shape_problem(device)
            if problem is not None:
                return f"devices.{name}.{problem}"
    return None


def _decoupling_problem(dc: DecouplingResult) -> str | None:
    for key, per_axis, size in (("undesired_um", dc.undesired_um, 2), ("omega", dc.omega, 0)):
        for axis in "xyz":
            if axis not in per_axis:
                return f"{key}: expected the axes x, y and z, {axis} is missing"
            value = per_axis[axis]
            if size and (not isinstance(value, list) or len(value) != size):
                return f"{key}.{axis}: expected [min, max]"
    if dc.samples_um is None:
        return None
    for k, row in enumerate(dc.samples_um):
        if len(row) != 3:
            return f"samples_um.{k}: expected 3 values (x, y, z), got {len(row)}"
    if dc.segment is None or len(dc.segment) != len(dc.samples_um):
        return "segment: expected the moving axis of each of samples_um"
    return None


def load_results(path: str | os.PathLike[str]) -> dict[str, object]:
    """Read results.json, validated, as the JSON object; FormatError if it is not one."""
    raw = read_versioned_json(path, RESULTS_FORMATS)
    parse_schema(Results, raw, Path(path))
    return raw


def update_results(path: str | os.PathLike[str], parts: Mapping[str, object] | JsonRecord) -> Path:
    """Merge ``parts`` into results.json (one level deep per source), atomically, under the
    file's lock (two merges at once both land).

    ``parts`` are sections by name (JSON-like values, numpy arrays and numbers among them),
    or a record of them (an :class:`~microcal.procedures.evaluation_figures.Evaluation`).
    NaN becomes null: JSON has no NaN.
    """
    p = Path(path)
    sections = parts if isinstance(parts, Mapping) else parts.to_json()
    plain = _plain_object(sections)
    with locked_update(p):
        data: dict[str, object] = load_results(p) if p.exists() else {"format": RESULTS_FORMAT}
        for key, value in plain.items():
            current = data.get(key)
            if isinstance(value, dict) and isinstance(current, dict):
                for source, sub in value.items():
                    if isinstance(sub, dict) and isinstance(current.get(source), dict):
                        current[source].update(sub)
                    else:
                        current[source] = sub
            else:
                data[key] = value
        return write_text_atomic(p, json.dumps(data, indent=1, allow_nan=False) + "\n")
