"""Pose characteristics of ISO 9283:1998 ("Manipulating industrial robots - Performance
criteria and related test methods"), for positions (no orientation).

- Pose accuracy, clause 7.2.1: the difference between the commanded pose and the mean of
  the attained poses, per axis ``AP_x = x̄ - x_c`` ..., and as a distance
  ``AP_P = sqrt(AP_x² + AP_y² + AP_z²)`` (thesis Eq 5.2).
- Pose repeatability, clause 7.2.2: the radius of the sphere around the mean attained pose,
  ``RP = l̄ + 3 S_l`` with ``l_j`` the distance of attained pose j from the mean, ``l̄`` their
  mean and ``S_l`` their standard deviation (n - 1 in the denominator).
- Multi-directional pose accuracy variation, clause 7.2.3: the largest distance between the
  barycentres of the poses attained when one commanded pose is approached from different
  directions, ``vAP_P = max sqrt((x̄_h - x̄_k)² + (ȳ_h - ȳ_k)² + (z̄_h - z̄_k)²)`` over the
  pairs of directions h, k.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import InputError

__all__ = [
    "PoseStatistics",
    "multi_directional_variation",
    "pose_accuracy",
    "pose_repeatability",
    "pose_statistics",
]


def _arrivals(arrived_um: ArrayLike, minimum: int) -> FloatArray:
    a = np.asarray(arrived_um, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    a = as_array(a, "arrived_um", (None, 3))
    if a.shape[0] < minimum:
        raise InputError(
            f"arrived_um: expected at least {minimum} attained poses, got {a.shape[0]}"
        )
    return a


def pose_accuracy(desired_um: ArrayLike, arrived_um: ArrayLike) -> tuple[FloatArray, float]:
    """Pose accuracy of one commanded pose (ISO 9283 clause 7.2.1; thesis Eq 5.2).

    Parameters
    ----------
    desired_um : (3,) float
        The commanded position, µm.
    arrived_um : (n, 3) or (3,) float
        The n attained positions, µm.

    Returns
    -------
    ap_um : (3,) float
        ``AP_x, AP_y, AP_z``: mean attained minus commanded, per axis.
    ap_p_um : float
        ``AP_P``: the distance between the mean attained and the commanded position.
    """
    c = as_array(desired_um, "desired_um", (3,))
    a = _arrivals(arrived_um, 1)
    ap = a.mean(axis=0) - c
    return ap, float(np.linalg.norm(ap))


def pose_repeatability(arrived_um: ArrayLike) -> float:
    """Pose repeatability ``RP = l̄ + 3 S_l`` (ISO 9283 clause 7.2.2).

    Parameters
    ----------
    arrived_um : (n, 3) float
        n >= 2 attained positions of one commanded pose, µm.
    """
    a = _arrivals(arrived_um, 2)
    dist = np.linalg.norm(a - a.mean(axis=0), axis=1)
    return float(dist.mean() + 3.0 * dist.std(ddof=1))


@dataclass(frozen=True)
class PoseStatistics:
    """Accuracy and repeatability of one commanded pose, µm."""

    desired_um: FloatArray  # (3,)
    mean_arrival_um: FloatArray  # (3,)
    ap_um: FloatArray  # (3,)
    ap_p_um: float
    rp_um: float | None  # None with a single attained pose
    n: int

    def as_dict(self) -> dict[str, object]:
        """The per-pose object of results.json."""
        return {
            "desired_um": self.desired_um.tolist(),
            "mean_arrival_um": self.mean_arrival_um.tolist(),
            "ap_um": self.ap_um.tolist(),
            "ap_p_um": self.ap_p_um,
            "rp_um": self.rp_um,
            "n": self.n,
        }


def pose_statistics(desired_um: ArrayLike, arrived_um: ArrayLike) -> PoseStatistics:
    """AP per axis, AP_P and (for n >= 2) RP of one commanded pose."""
    c = as_array(desired_um, "desired_um", (3,))
    a = _arrivals(arrived_um, 1)
    ap, ap_p = pose_accuracy(c, a)
    rp = pose_repeatability(a) if a.shape[0] >= 2 else None
    return PoseStatistics(c, a.mean(axis=0), ap, ap_p, rp, int(a.shape[0]))


def multi_directional_variation(arrived_by_direction: Sequence[ArrayLike]) -> float:
    """Multi-directional pose accuracy variation ``vAP_P`` of one pose (ISO 9283 clause 7.2.3).

    Parameters
    ----------
    arrived_by_direction : list of (n_k, 3) float
        Per approach direction (two or more), the positions attained, µm.

    Returns
    -------
    float
        The largest distance between two directions' barycentres, µm.
    """
    if len(arrived_by_direction) < 2:
        raise InputError(
            f"arrived_by_direction: expected two or more approach directions, got "
            f"{len(arrived_by_direction)}"
        )
    centres = np.array([_arrivals(a, 1).mean(axis=0) for a in arrived_by_direction])
    gaps = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
    return float(gaps.max())
