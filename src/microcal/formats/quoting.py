"""Quoting what a file holds in a message: short and escaped, never the file itself.

A message may show the piece of an input file at fault (a cell ``dx_um = 'abc'``, a format
name) so the user finds it, but never more than a few characters of it, with every control
and non-ASCII character escaped: the file may be anything (another program's data, a
secret a link points to), and the message lands in terminals and logs.
"""

from __future__ import annotations

__all__ = ["EXCERPT_CHARS", "excerpt"]

#: Most characters of a file's text a message quotes.
EXCERPT_CHARS = 40


def excerpt(value: object, limit: int = EXCERPT_CHARS) -> str:
    """``value`` as Python writes it (a string quoted: ``'abc'``), escaped, with at most
    ``limit`` characters of a string (``...`` marks a cut)."""
    if not isinstance(value, str):
        shown = ascii(value)
        return shown if len(shown) <= limit else shown[:limit] + "..."
    quoted = ascii(value[:limit])
    return quoted + "..." if len(value) > limit else quoted
