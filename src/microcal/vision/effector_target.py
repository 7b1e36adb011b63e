"""The end-effector's target as a rig names it: a board or a tool's tip, with a hint.

Wherever a board is the end-effector's target (a rig file's ``board``, a further device's
``[manipulators.NAME]`` ``board``, a simulated rig's ``[overrides] board``, ``measure
--target``), a tool's tip is accepted too (``tip``, ``tip:pipette``, ``tip:needle:20:5``;
:mod:`~microcal.vision.tip_target`). :func:`parse_effector_target` reads either, as
:func:`~microcal.vision.targets.parse_spec` does, and adds to its one-line refusal the fix
of a near miss: a misspelt tool kind (``tip:needel``: did you mean ``tip:needle``?) or a
tool named without ``tip:`` (``needle:20:5``: write ``tip:needle:20:5``).
"""

from __future__ import annotations

import difflib

from ..errors import InputError
from .targets import Target, parse_spec
from .tip_target import TIP_KINDS, TipTarget, is_tip_spec

__all__ = ["parse_effector_target"]

#: The tool kinds a spec may name after ``tip:`` (``any`` is the default, never a near miss).
_TOOLS = tuple(k for k in TIP_KINDS if k != "any")


def parse_effector_target(spec: str) -> Target | TipTarget:
    """Parse the end-effector's target: a board or a tool's tip.

    Parameters
    ----------
    spec : str
        A board spec (``chessboard:4x3:400``) or a tip spec (``tip[:KIND][:TAPER_DEG][:TIP_UM]``).

    Returns
    -------
    Target or TipTarget

    Raises
    ------
    InputError
        One line: the parser's own, with the fix of a near miss when there is one.
    """
    try:
        return parse_spec(spec)
    except InputError as exc:
        hint = _near_miss(spec)
        if not hint:
            raise
        if is_tip_spec(spec):  # the tip parser's line, and the fix
            raise InputError(f"{exc}; {hint}") from None
        raise InputError(f"target {spec!r}: {hint}") from None


def _near_miss(spec: str) -> str:
    """The fix of a tip spec that is nearly right, or ``""``."""
    parts = spec.strip().lower().split(":")
    if is_tip_spec(spec):  # tip:KIND...: a misspelt kind
        kind = parts[1] if len(parts) > 1 else ""
        if not kind or kind in TIP_KINDS or kind.replace(".", "").isdigit():
            return ""
        near = _nearest(kind, _TOOLS)
        return f"did you mean {':'.join(['tip', near, *parts[2:]])}?" if near else ""
    near = _nearest(parts[0], (*_TOOLS, "tip"))  # a tool without tip:, or tip misspelt
    if near is None:
        return ""
    fixed = ":".join(["tip", *parts[1:]] if near == "tip" else ["tip", near, *parts[1:]])
    return f"a tool's tip is written tip[:KIND][:TAPER_DEG][:TIP_UM]; did you mean {fixed}?"


def _nearest(word: str, choices: tuple[str, ...]) -> str | None:
    near = difflib.get_close_matches(word, choices, n=1, cutoff=0.75)
    return near[0] if near else None
