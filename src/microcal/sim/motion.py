"""Motion with memory and noise: reversal error from play operators, positioning scatter and
step quantisation of the simulated stick-slip joints.

**Reversal error with memory** (Prandtl-Ishlinskii): each joint's reversal error is its half
gap (:meth:`~microcal.sim.kinematics.TrueKinematics.hysteresis_at_um`) times an *effective
direction* ``h`` in [-1, 1], the weighted sum of K play (backlash) operators of radii
``r_k``::

    y_k <- clip(y_k, x - r_k, x + r_k)       (each time the joint moves to x)
    h = sum_k w_k (x - y_k) / r_k            (weights summing to 1)

After a move longer than twice the largest radius every operator is saturated and ``h`` is
the sign of that move: the switch on the last move's sign of the ideal simulator. A short
reversal turns only the small operators over, so it gives a smaller offset than a long one
(minor loops), and where a joint ends depends on how far it travelled since it last turned.
A fixed approach of at least :meth:`PlayHysteresis.saturation_um` lands every operator at
+1, whatever came before.

**Motion noise**: a move of a joint ends on its stick-slip step grid counted from where the
move began (``start + round((d - start) / step) * step``), then off by a random scatter of
standard deviation ``scatter_um``: the positioning repeatability of a closed-loop
stick-slip stage. A joint that is not moved keeps its place exactly.

Sizes and their sources are in ``docs/simulator.md`` ("Motion with memory and noise").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import InputError

__all__ = ["MotionNoise", "PlayHysteresis", "play_radii_um"]


def play_radii_um(largest_um: float, count: int = 5, span: float = 16.0) -> FloatArray:
    """``count`` play radii spaced geometrically from ``largest_um / span`` to ``largest_um``."""
    out: FloatArray = np.geomspace(largest_um / span, largest_um, count)
    return out


@dataclass(frozen=True, eq=False)
class PlayHysteresis:
    """The play operators of each joint.

    Attributes
    ----------
    radii_um : (3, K) float
        Each joint's play radii, > 0, µm.
    weights : (3, K) float
        Their weights, >= 0, each row summing to 1.
    """

    radii_um: FloatArray
    weights: FloatArray

    def __post_init__(self) -> None:
        r = as_array(self.radii_um, "radii_um", (3, None))
        w = as_array(self.weights, "weights", r.shape)
        if np.any(r <= 0) or np.any(w < 0) or not np.allclose(w.sum(axis=1), 1.0):
            raise InputError(
                "play: expected radii > 0 µm and weights >= 0 summing to 1 per joint, got "
                f"radii {r.tolist()} and weights {w.tolist()}"
            )

    def saturation_um(self) -> float:
        """The travel after which every operator is saturated: twice the largest radius, µm."""
        return float(2.0 * self.radii_um.max())

    def start_state_um(self, x_um: ArrayLike, signs: ArrayLike | None = None) -> FloatArray:
        """Operator states of joints at ``x_um`` (3,) that arrived moving in ``signs``
        (+1 by default), (3, K) µm."""
        x = as_array(x_um, "x_um", (3,))
        s = np.ones(3) if signs is None else as_array(signs, "signs", (3,))
        out: FloatArray = x[:, None] - s[:, None] * self.radii_um
        return out

    def moved(self, state_um: FloatArray, x_um: FloatArray) -> FloatArray:
        """The states after the joints moved (monotonically each) to ``x_um`` (3,), (3, K)."""
        out: FloatArray = np.clip(state_um, x_um[:, None] - self.radii_um,
                                  x_um[:, None] + self.radii_um)  # fmt: skip
        return out

    def direction(self, state_um: FloatArray, x_um: FloatArray) -> FloatArray:
        """Each joint's effective approach direction in [-1, 1] at ``x_um`` (3,), (3,)."""
        h = (x_um[:, None] - state_um) / self.radii_um
        out: FloatArray = np.sum(self.weights * np.clip(h, -1.0, 1.0), axis=1)
        return out


@dataclass(frozen=True)
class MotionNoise:
    """Where a commanded joint move really ends.

    Attributes
    ----------
    scatter_um : (3,) float
        Standard deviation of each joint's end point about its step, µm (0: none).
    step_um : (3,) float
        Each joint's stick-slip step, µm; a move ends a whole number of steps from where it
        began (0: any point).
    """

    scatter_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    step_um: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("scatter_um", "step_um"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0) or np.any(v > 10):
                raise InputError(f"{name}: expected three values in [0, 10] µm, got "
                                 f"{getattr(self, name)!r}")  # fmt: skip

    @property
    def active(self) -> bool:
        """Whether it changes any move."""
        return bool(np.any(np.asarray(self.scatter_um) > 0) or np.any(np.asarray(self.step_um) > 0))

    def end_um(
        self, start_um: FloatArray, target_um: FloatArray, rng: np.random.Generator
    ) -> FloatArray:
        """Where joints moving from ``start_um`` to ``target_um`` (3,) stop, (3,) µm.

        The scatter is drawn for all three joints every call (so that the stream does not
        depend on which joints moved); a joint that does not move stays put.
        """
        step = np.asarray(self.step_um, dtype=np.float64)
        delta = target_um - start_um
        with np.errstate(divide="ignore", invalid="ignore"):
            snapped = np.where(step > 0, np.round(delta / np.where(step > 0, step, 1.0)) * step,
                               delta)  # fmt: skip
        scatter = rng.normal(0.0, 1.0, 3) * np.asarray(self.scatter_um, dtype=np.float64)
        moving = delta != 0
        out: FloatArray = np.where(moving, start_um + snapped + scatter, start_um)
        return out
