"""``results.json``: the figures of evaluation runs (and of the demo), merged as they come.

Its schema is :class:`~microcal.formats.records.Results`: every section optional, any other
key kept. NaN is written as null (JSON has no NaN).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import write_text_atomic
from .file_lock import locked_update
from .json_file import parse_schema, read_versioned_json
from .records import RESULTS_FORMAT, RESULTS_FORMATS, Results

__all__ = ["RESULTS_FORMAT", "Results", "load_results", "read_results", "update_results"]


def _plain(value: Any) -> Any:
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
    return value


def read_results(path: str | os.PathLike[str]) -> Results:
    """Read and validate results.json as a typed document.

    Raises
    ------
    FormatError
        Missing file, not JSON, an unknown format version, or a section of the wrong shape
        (the message names the key).
    """
    raw = read_versioned_json(path, RESULTS_FORMATS)
    return parse_schema(Results, raw, Path(path))


def load_results(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read results.json, validated, as the JSON object; FormatError if it is not one."""
    raw = read_versioned_json(path, RESULTS_FORMATS)
    parse_schema(Results, raw, Path(path))
    return raw


def update_results(path: str | os.PathLike[str], parts: dict[str, Any]) -> Path:
    """Merge ``parts`` into results.json (one level deep per source), atomically, under the
    file's lock (two merges at once both land).

    NaN becomes null: JSON has no NaN.
    """
    p = Path(path)
    plain = _plain(parts)
    with locked_update(p):
        data: dict[str, Any] = load_results(p) if p.exists() else {"format": RESULTS_FORMAT}
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
