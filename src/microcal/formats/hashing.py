"""The SHA-256 of a file, as run.json, the journal and provenance record it."""

from __future__ import annotations

import hashlib
import os

from .safe_open import opened_regular

__all__ = ["sha256_file"]


def sha256_file(path: str | os.PathLike[str], *, link_ok: bool = False) -> str:
    """Hex SHA-256 of a file's bytes (read in blocks of 1 MiB).

    Only a regular file is read; a symbolic link only with ``link_ok`` (a file the user
    named: :mod:`.safe_open`).
    """
    h = hashlib.sha256()
    with opened_regular(path, link_ok=link_ok) as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
