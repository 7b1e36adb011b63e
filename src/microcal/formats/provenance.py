"""The provenance every file microcal writes carries: software, time and input hashes."""

from __future__ import annotations

import datetime as _dt
import os
from collections.abc import Mapping

from .._version import __version__
from ..json_value import JsonValue
from .hashing import sha256_file

__all__ = ["provenance"]


def provenance(
    inputs: Mapping[str, str | os.PathLike[str]] | None = None, **extra: JsonValue
) -> dict[str, JsonValue]:
    """Software version, UTC time and the SHA-256 of each input file (and ``extra``)."""
    return {
        "software": f"microcal {__version__}",
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "inputs": {
            name: {"path": str(p), "sha256": sha256_file(p, link_ok=True)}
            for name, p in (inputs or {}).items()
        },
        **extra,
    }
