"""Reading microcal's versioned JSON files with one-line errors, and the base of their schemas.

Every JSON file microcal writes has a ``format`` key, ``NAME/VERSION`` (``microcal.calibration/1``).
A reader names the versions it reads; a file of the right name but another version fails with
one message naming the version found and the versions this microcal reads. Each file's schema
derives from :class:`FileSchema`: unknown keys are kept (files grow by adding keys), NaN and
infinity are refused, and a malformed key is reported by its path
(``manipulators.m1.model.kind: Input should be 'matrix' or 'polynomial'``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from .._validation import excerpt
from .._version import __version__
from ..errors import FormatError
from .safe_open import read_regular_text

__all__ = [
    "FileSchema",
    "check_format",
    "check_json_output",
    "parse_schema",
    "read_json_object",
    "read_versioned_json",
    "validation_message",
]


class FileSchema(BaseModel):
    """The base of every file schema: unknown keys are kept, NaN and infinity refused.

    Subclasses name the keys they read; any other key of the file stays in the model's
    extras (``model_extra``) and is written back by ``model_dump``.
    """

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


S = TypeVar("S", bound=BaseModel)


def validation_message(exc: ValidationError) -> str:
    """The first problem pydantic found, as ``key.path: message`` for a one-line error."""
    err = exc.errors()[0]
    loc = ".".join(str(part) for part in err["loc"]) or "(top level)"
    return f"{loc}: {err['msg']}"


def parse_schema(schema: type[S], raw: object, where: str | os.PathLike[str]) -> S:
    """``raw`` validated by ``schema``; FormatError ``WHERE: key.path: message`` otherwise."""
    try:
        return schema.model_validate(raw)
    except ValidationError as exc:
        raise FormatError(f"{where}: {validation_message(exc)}") from None


def read_json_object(
    path: str | os.PathLike[str], missing_hint: str = "", *, link_ok: bool = False
) -> dict[str, object]:
    """A file's JSON object, as parsed (its values to be validated by the reader).

    ``link_ok``: the user named the file, which may be a symbolic link to one
    (:mod:`.safe_open`).

    Raises
    ------
    FormatError
        No such file (with ``missing_hint``), not UTF-8 JSON, or not an object; a symbolic
        link (unless ``link_ok``), a FIFO or a device.
    """
    p = Path(path)
    try:
        raw = json.loads(read_regular_text(p, link_ok=link_ok))
    except FormatError:
        raise  # a link, a FIFO, a device: safe_open's own line
    except FileNotFoundError:
        raise FormatError(f"{p}: no such file{missing_hint}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(f"{p}: not a JSON file ({exc})") from None
    except (RecursionError, ValueError) as exc:  # nested too deep, an integer of 4300 digits
        raise FormatError(f"{p}: not a JSON file microcal reads ({type(exc).__name__})") from None
    if not isinstance(raw, dict):
        raise FormatError(f"{p}: expected a JSON object, got {type(raw).__name__}")
    out: dict[str, object] = raw
    return out


def _name_and_version(fmt: str) -> tuple[str, str]:
    name, _, version = fmt.rpartition("/")
    return (name, version) if name else (fmt, "")


def check_format(path: str | os.PathLike[str], found: object, formats: tuple[str, ...]) -> None:
    """Refuse a ``format`` value that is not one of ``formats`` (all versions of one name).

    A file of the right name but an unknown version gets its own message, naming the version
    found and the versions this microcal reads.
    """
    if found in formats:
        return
    name, _ = _name_and_version(formats[0])
    if isinstance(found, str):
        found_name, found_version = _name_and_version(found)
        if found_name == name:
            known = ", ".join(_name_and_version(f)[1] for f in formats if f.startswith(name))
            raise FormatError(
                f"{path}: {name} version {excerpt(found_version)} is not one this microcal "
                f"({__version__}) reads; it reads version {known} (a newer microcal may have "
                f"written this file)"
            )
    raise FormatError(f"{path}: expected format {formats[0]!r}, got {excerpt(found)}")


def read_versioned_json(
    path: str | os.PathLike[str],
    formats: tuple[str, ...],
    missing_hint: str = "",
    *,
    link_ok: bool = False,
) -> dict[str, object]:
    """A JSON object whose ``format`` is one of ``formats`` (the versions this microcal reads),
    as parsed.

    Raises
    ------
    FormatError
        No such file (with ``missing_hint``), not JSON, another format, or a version of the
        format that this microcal does not read.
    """
    raw = read_json_object(path, missing_hint, link_ok=link_ok)
    check_format(Path(path), raw.get("format"), formats)
    return raw


def check_json_output(
    path: str | os.PathLike[str], fmt: str, example: str, option: str = "--out"
) -> Path:
    """Refuse, before any work, an output that cannot be written or is not ours to replace.

    ``path`` may be new, or a file of the format ``fmt`` (its name, any version) that microcal
    wrote; a directory, a file of another kind or a place without write permission is an
    ``InputError`` naming the option and the fix (``example``: a file name to suggest).
    """
    from .outputs import check_output

    name = _name_and_version(fmt)[0]

    def foreign(p: Path) -> str | None:
        try:
            found = json.loads(read_regular_text(p)).get("format")
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError, RecursionError,
                FormatError, ValueError):  # fmt: skip
            found = None
        if not isinstance(found, str):
            return "a file microcal did not write"
        return None if _name_and_version(found)[0] == name else f"a {excerpt(found)} file"

    return check_output(path, kind=f"a {name} file", foreign=foreign, example=example,
                        option=option)  # fmt: skip
