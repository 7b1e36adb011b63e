"""The simulated focus drive: the objective moved along z by a motor, with its own errors.

The drive reads back what it was told (an open-loop stepper, as most microscopes' focus
drives are); where the objective really goes differs from it by:

- a **scale error** of its travel (the leadscrew's pitch and the gear's ratio; microscope
  focus drives are specified to a few tenths of a per cent): ``true = (1 + scale) command``;
- a **tilt** between the focus axis and the optical axis (a focus block mounted a fraction of
  a degree off): moving the focus by ``dz`` also shifts the view sideways by
  ``dz sin(tilt)`` towards ``tilt_azimuth_deg``;
- **backlash**: a dead band of ``backlash_um`` that the command crosses on every reversal
  before the objective follows (a leadscrew's lost motion, tenths of a micron after the
  maker's compensation); the drive's zero was set approaching from below, so a position
  approached from below is where it reads and one approached from above lies
  ``backlash_um`` higher (the depth procedures approach every focus from below);
- **scatter**: each move ends off by a normal draw of ``noise_um`` (the drive's
  repeatability, some tens of nanometres).

Each move takes ``travel / speed_um_s + settle_s`` on the drive's clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray, check_number
from ..devices.base import Clock
from ..errors import LimitError

__all__ = ["FocusDrive", "FocusErrors"]


@dataclass(frozen=True)
class FocusErrors:
    """A focus drive's errors (see the module docstring).

    Attributes
    ----------
    scale : float
        Relative error of the travel (0.003: 3 µm too far over 1 mm).
    tilt_deg : float
        Angle between the focus axis and the optical axis, degrees.
    tilt_azimuth_deg : float
        Direction in the image plane ({G}'s x-y) towards which the view shifts as the
        objective rises, from +x towards +y, degrees.
    backlash_um : float
        Lost motion on a reversal, µm.
    noise_um : float
        Standard deviation of where a move ends, µm.
    """

    scale: float = 0.003
    tilt_deg: float = 0.3
    tilt_azimuth_deg: float = 30.0
    backlash_um: float = 0.3
    noise_um: float = 0.02

    def __post_init__(self) -> None:
        check_number("scale", self.scale, low=-0.1, high=0.1)
        check_number("tilt_deg", self.tilt_deg, low=0, high=10)
        check_number("tilt_azimuth_deg", self.tilt_azimuth_deg, low=-360, high=360)
        check_number("backlash_um", self.backlash_um, low=0, high=100)
        check_number("noise_um", self.noise_um, low=0, high=10)

    @property
    def axis(self) -> FloatArray:
        """The true direction of the focus's travel in {G} (z up), unit (3,)."""
        t, a = math.radians(self.tilt_deg), math.radians(self.tilt_azimuth_deg)
        return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])


class FocusDrive:
    """A motorised focus: the objective's z, commanded in µm from its home.

    Parameters
    ----------
    clock : Clock
    rng : numpy.random.Generator
        Source of the moves' scatter.
    errors : FocusErrors
    limits_um : (float, float)
        The commanded range; a move outside it is refused (:class:`LimitError`).
    speed_um_s, settle_s : float
        Travel speed and the time to settle after a move.
    """

    def __init__(
        self,
        clock: Clock,
        rng: np.random.Generator,
        errors: FocusErrors | None = None,
        *,
        limits_um: tuple[float, float] = (-500.0, 500.0),
        speed_um_s: float = 500.0,
        settle_s: float = 0.03,
    ) -> None:
        self.clock = clock
        self.rng = rng
        self.errors = errors or FocusErrors()
        self.limits_um = (float(limits_um[0]), float(limits_um[1]))
        self.speed_um_s = check_number("speed_um_s", speed_um_s, above=0)
        self.settle_s = check_number("settle_s", settle_s, low=0)
        self._command = 0.0
        # the mechanism behind the dead band: at home, come from below
        self._follower = -self.errors.backlash_um / 2.0
        self._scatter = 0.0
        #: Moves made so far.
        self.moves = 0

    def position_um(self) -> float:
        """The drive's readout: the last commanded position, µm."""
        return self._command

    def move_to(self, z_um: float) -> None:
        """Move the objective to ``z_um`` (commanded) and wait until it has settled.

        Raises
        ------
        LimitError
            ``z_um`` outside :attr:`limits_um` (nothing moved).
        """
        z = float(z_um)
        lo, hi = self.limits_um
        if not (math.isfinite(z) and lo <= z <= hi):
            raise LimitError(
                f"focus: {z_um!r} µm is outside the focus drive's range {lo:g} to {hi:g} µm"
            )
        half = self.errors.backlash_um / 2.0
        if z - self._follower > half:
            self._follower = z - half
        elif self._follower - z > half:
            self._follower = z + half
        travel = abs(z - self._command)
        self._command = z
        self._scatter = float(self.rng.normal(0.0, self.errors.noise_um))
        self.moves += 1
        self.clock.sleep(travel / self.speed_um_s + self.settle_s)

    def objective_offset_um(self) -> FloatArray:
        """Where the objective truly is, relative to its home, (3,) µm in {G}."""
        e = self.errors
        lifted = self._follower + e.backlash_um / 2.0  # exact when approached from below
        out: FloatArray = ((1.0 + e.scale) * lifted + self._scatter) * e.axis
        return out
