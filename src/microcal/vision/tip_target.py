"""The tool-tip target: a spec of the tool whose tip the vision finds.

A tip spec is ``tip[:KIND][:TAPER_DEG][:TIP_UM]``:

- ``KIND``: ``pipette`` (glass: two dark edges, a lighter lumen), ``needle`` (an opaque cone
  with a rounded end), ``jaw`` (a gripper jaw: a flat tapered plate, rounded corner) or
  ``any`` (the default: an outline whose inside may be dark or light);
- ``TAPER_DEG``: the full angle between the taper's two outer edges, degrees (optional; when
  given, the end's foreshortening follows from the angle seen);
- ``TIP_UM``: the opening's (pipette) or the rounded end's (needle, jaw) diameter, µm
  (optional).

``tip:pipette:10:1`` is a patch pipette of 10 degrees with a 1 µm opening. The *tip point*
(``docs/conventions.md``) is on the tool's axis: the centre of the rounded end (needle, jaw)
or of the opening's ring (pipette).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Literal

from ..errors import InputError

__all__ = ["TIP_KINDS", "TipTarget", "is_tip_spec", "parse_tip"]

TipKind = Literal["any", "pipette", "needle", "jaw"]
TIP_KINDS: tuple[TipKind, ...] = ("any", "pipette", "needle", "jaw")
_SPEC = re.compile(r"^tip(?::([a-z]+))?(?::([0-9.]+))?(?::([0-9.]+))?$", re.IGNORECASE)


@dataclass(frozen=True)
class TipTarget:
    """A tool whose tip is the target.

    Attributes
    ----------
    kind : {"any", "pipette", "needle", "jaw"}
    taper_deg : float
        Full angle between the outer edges, degrees; 0 when not given.
    tip_um : float
        Diameter of the opening or of the rounded end, µm; 0 when not given.
    """

    kind: TipKind = "any"
    taper_deg: float = 0.0
    tip_um: float = 0.0

    @property
    def spec(self) -> str:
        """The spec string this target parses from."""
        out = f"tip:{self.kind}"
        if self.taper_deg:
            out += f":{self.taper_deg:g}"
            if self.tip_um:
                out += f":{self.tip_um:g}"
        return out

    @property
    def half_angle_rad(self) -> float:
        """Half the taper's angle (rad), NaN when not given."""
        return math.radians(self.taper_deg) / 2 if self.taper_deg else float("nan")


def is_tip_spec(spec: str) -> bool:
    """Whether a target spec names a tool tip (``tip`` or ``tip:...``)."""
    s = spec.strip().lower()
    return s == "tip" or s.startswith("tip:")


def parse_tip(spec: str) -> TipTarget:
    """Parse a tip spec (see the module docstring).

    Raises
    ------
    InputError
        One line with the expected form.
    """
    m = _SPEC.match(spec.strip())
    form = "expected tip[:KIND][:TAPER_DEG][:TIP_UM] with KIND pipette, needle, jaw or any"
    if not m:
        raise InputError(f"target {spec!r}: {form}, e.g. tip:pipette:10:1")
    kind = (m.group(1) or "any").lower()
    if kind not in TIP_KINDS:
        raise InputError(f"target {spec!r}: {form}, got kind {kind!r}")
    try:
        taper = float(m.group(2)) if m.group(2) else 0.0
        tip = float(m.group(3)) if m.group(3) else 0.0
    except ValueError:
        raise InputError(f"target {spec!r}: the taper and tip size must be numbers") from None
    if m.group(2) and not 0.5 <= taper <= 90:
        raise InputError(f"target {spec!r}: expected a taper of 0.5 to 90 degrees, got {taper:g}")
    if m.group(3) and not 0 < tip <= 1000:
        raise InputError(f"target {spec!r}: expected a tip of 0 to 1000 µm, got {tip:g}")
    return TipTarget(kind, taper, tip)  # type: ignore[arg-type,unused-ignore]
