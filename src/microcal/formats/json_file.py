"""Reading microcal's versioned JSON files with one-line errors."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from ..errors import FormatError

__all__ = ["read_versioned_json", "validation_message"]


def validation_message(exc: ValidationError) -> str:
    """The first problem pydantic found, as ``key.path: message`` for a one-line error."""
    err = exc.errors()[0]
    loc = ".".join(str(part) for part in err["loc"]) or "(top level)"
    return f"{loc}: {err['msg']}"


def read_versioned_json(
    path: str | os.PathLike[str], formats: tuple[str, ...], missing_hint: str = ""
) -> dict[str, Any]:
    """A JSON object whose ``format`` is one of ``formats``.

    Raises
    ------
    FormatError
        No such file (with ``missing_hint``), not JSON, or another format.
    """
    p = Path(path)
    try:
        raw = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FormatError(f"{p}: no such file{missing_hint}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(f"{p}: not a JSON file ({exc})") from None
    if not isinstance(raw, dict) or raw.get("format") not in formats:
        found = raw.get("format") if isinstance(raw, dict) else type(raw).__name__
        raise FormatError(f"{p}: expected format {formats[0]!r}, got {found!r}")
    return raw
