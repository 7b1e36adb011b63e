"""Rig time: what a calibration costs on the rig, per pose and in all.

A pose costs its moves (the approach and the move to it, until the device says it has
stopped), its settling (the fixed wait, or the vision check, whose last frames are the
pose's frames) and the rest until the next pose begins (the other cameras' frames, storing
them). The journal records when each pose began (``sim_time_s``: the rig's clock), its
``move_s`` and its ``settle_s``; a pose's rig time is the time from its start to the next
pose's start, and for the last pose its move and settling plus the median of the other
poses' rest. The fits an adaptive design makes between poses are rig time too (the rig
waits for them); a fixed design fits once the images are stored, when the rig is free.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray

__all__ = ["RigTime", "pose_rig_times_s"]


def pose_rig_times_s(
    start_s: Sequence[float], move_s: Sequence[float], settle_s: Sequence[float]
) -> FloatArray:
    """Each pose's rig time (module docstring), (n,) s.

    Parameters
    ----------
    start_s, move_s, settle_s : (n,) float
        When each pose began (in the order acquired), its moves and its settling, s.
    """
    start = np.asarray(start_s, dtype=np.float64)
    own = np.asarray(move_s, dtype=np.float64) + np.asarray(settle_s, dtype=np.float64)
    if start.size == 0:
        return np.zeros(0)
    gaps = np.diff(start)
    rest = gaps - own[:-1]
    out = np.empty(start.size)
    out[:-1] = gaps
    out[-1] = own[-1] + (float(np.median(np.maximum(rest, 0.0))) if rest.size else 0.0)
    return out


@dataclass(frozen=True)
class RigTime:
    """A calibration's rig time: each pose's, their moves and settling, and fits between."""

    per_pose_s: FloatArray
    moves_s: float
    settle_s: float
    fits_s: float = 0.0

    @property
    def total_s(self) -> float:
        """The whole calibration, s."""
        return float(self.per_pose_s.sum()) + self.fits_s

    def to_json(self) -> dict[str, object]:
        """The ``rig_time`` object of results.json."""
        return {
            "total_s": self.total_s,
            "poses": int(self.per_pose_s.size),
            "mean_per_pose_s": float(self.per_pose_s.mean()) if self.per_pose_s.size else 0.0,
            "moves_s": self.moves_s,
            "settle_s": self.settle_s,
            "fits_s": self.fits_s,
            "per_pose_s": [round(float(v), 6) for v in self.per_pose_s],
        }

    @classmethod
    def of_records(
        cls, start_s: Sequence[float], move_s: Sequence[float], settle_s: Sequence[float],
        fits_s: float = 0.0,
    ) -> RigTime:  # fmt: skip
        """From the journal's figures of each pose (module docstring)."""
        return cls(pose_rig_times_s(start_s, move_s, settle_s), float(np.sum(move_s)),
                   float(np.sum(settle_s)), fits_s)  # fmt: skip
