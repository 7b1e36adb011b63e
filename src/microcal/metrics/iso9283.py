"""Pose characteristics of ISO 9283:1998 ("Manipulating industrial robots - Performance
criteria and related test methods"), for positions (no orientation).

- Pose accuracy, clause 7.2.1: the difference between the commanded pose and the mean of
  the attained poses, per axis ``AP_x = x̄ - x_c`` ..., and as a distance
  ``AP_P = sqrt(AP_x² + AP_y² + AP_z²)`` (thesis Eq 5.2).
- Pose repeatability, clause 7.2.2: the radius of the sphere around the mean attained pose,
  ``RP = l̄ + 3 S_l`` with ``l_j`` the distance of attained pose j from the mean, ``l̄`` their
  mean and ``S_l`` their standard deviation (n - 1 in the denominator).
- Multi-directional pose accuracy variation, clause 7.3: the largest distance between the
  barycentres of the poses attained when one commanded pose is approached from different
  directions, ``vAP_P = max sqrt((x̄_h - x̄_k)² + (ȳ_h - ȳ_k)² + (z̄_h - z̄_k)²)`` over the
  pairs of directions h, k.
- Distance accuracy and repeatability, clause 7.4 (7.4.1, 7.4.2): between two commanded
  poses at the commanded distance ``D_c = |P_c1 - P_c2|``, each cycle j attains
  ``D_j = |P_1j - P_2j|``; ``AD_P = mean(D_j) - D_c`` and ``RD = 3 S_D`` (S_D with n - 1),
  and per axis with the signed differences ``D_xj = x_1j - x_2j``: ``AD_x = mean(D_xj) -
  D_cx``, ``RD_x = 3 S_Dx``.
- Pose stabilisation time, clause 7.5: the time from the "attained pose" signal until the
  position stays within a band around where it comes to rest.
- Drift of pose characteristics, clause 7.7: ``dAP = |AP(t_first) - AP(t_last)|`` over a
  long run, and likewise ``dRP``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import InputError
from ..json_value import JsonValue

__all__ = [
    "DistanceStatistics",
    "PoseStatistics",
    "distance_statistics",
    "drift",
    "multi_directional_variation",
    "pose_accuracy",
    "pose_repeatability",
    "pose_statistics",
    "stabilisation_time_s",
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

    def as_dict(self) -> dict[str, JsonValue]:
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
    """Multi-directional pose accuracy variation ``vAP_P`` of one pose (ISO 9283 clause 7.3).

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


@dataclass(frozen=True)
class DistanceStatistics:
    """Distance accuracy and repeatability between two commanded poses (clause 7.4), µm."""

    commanded_um: float  # D_c
    mean_um: float  # mean attained distance
    ad_um: FloatArray  # (3,) AD_x, AD_y, AD_z
    ad_p_um: float  # AD_P = mean distance - D_c (signed)
    rd_um: FloatArray  # (3,) RD_x, RD_y, RD_z (the ± is implied)
    rd_p_um: float  # RD = 3 S_D
    n: int

    def as_dict(self) -> dict[str, JsonValue]:
        """Plain dict for results.json."""
        return {"commanded_um": self.commanded_um, "mean_um": self.mean_um,
                "ad_um": self.ad_um.tolist(), "ad_p_um": self.ad_p_um,
                "rd_um": self.rd_um.tolist(), "rd_p_um": self.rd_p_um, "n": self.n}  # fmt: skip


def distance_statistics(
    commanded_1_um: ArrayLike,
    commanded_2_um: ArrayLike,
    attained_1_um: ArrayLike,
    attained_2_um: ArrayLike,
) -> DistanceStatistics:
    """Distance accuracy AD (ISO 9283 clause 7.4.1) and repeatability RD (clause 7.4.2).

    Parameters
    ----------
    commanded_1_um, commanded_2_um : (3,) float
        The two commanded poses, µm.
    attained_1_um, attained_2_um : (n, 3) float
        The poses attained in each of n >= 2 cycles (row j of both from cycle j), µm.

    Raises
    ------
    InputError
        Fewer than two cycles, or not as many attained poses of each.
    """
    c1 = as_array(commanded_1_um, "commanded_1_um", (3,))
    c2 = as_array(commanded_2_um, "commanded_2_um", (3,))
    a1 = _arrivals(attained_1_um, 2)
    a2 = _arrivals(attained_2_um, 2)
    if a1.shape != a2.shape:
        raise InputError(
            f"attained_2_um: expected as many cycles as attained_1_um ({a1.shape[0]}), got "
            f"{a2.shape[0]}"
        )
    dc = c1 - c2
    d_axes = a1 - a2  # (n, 3) signed per-axis distances
    d = np.linalg.norm(d_axes, axis=1)
    return DistanceStatistics(
        commanded_um=float(np.linalg.norm(dc)),
        mean_um=float(d.mean()),
        ad_um=d_axes.mean(axis=0) - dc,
        ad_p_um=float(d.mean() - np.linalg.norm(dc)),
        rd_um=3.0 * d_axes.std(axis=0, ddof=1),
        rd_p_um=float(3.0 * d.std(ddof=1)),
        n=int(d.size),
    )


def stabilisation_time_s(
    t_s: ArrayLike, p_um: ArrayLike, band_um: float, signal_s: float | None = None
) -> float | None:
    """Pose stabilisation time (ISO 9283 clause 7.5).

    The time from the "attained pose" signal until the position stays within ``band_um``
    of where it comes to rest (the last sample): from the signal to the first sample after
    which every sample is within the band.

    Parameters
    ----------
    t_s : (k,) float
        Sample times, increasing, s.
    p_um : (k, 3) float
        Positions, µm.
    band_um : float
        The limit (the standard leaves it to the manufacturer), µm, > 0.
    signal_s : float, optional
        When the device signalled arrival (default: the first sample).

    Returns
    -------
    float or None
        Seconds (0 when already within the band at the signal); None when the trace ends
        before the position has settled (only its last sample is within the band).
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    p = as_array(p_um, "p_um", (t.size, 3))
    if t.size < 2 or np.any(np.diff(t) <= 0):
        raise InputError("t_s: expected two or more increasing sample times")
    if not band_um > 0:
        raise InputError(f"band_um: expected a band > 0 µm, got {band_um!r}")
    start = float(t[0]) if signal_s is None else float(signal_s)
    keep = t >= start
    t, p = t[keep], p[keep]
    if t.size < 2:
        raise InputError("signal_s: expected two or more samples after the signal")
    outside = np.linalg.norm(p - p[-1], axis=1) > band_um
    if not outside.any():
        return 0.0
    last_out = int(np.flatnonzero(outside)[-1])
    if last_out >= t.size - 2:
        return None
    return float(t[last_out + 1] - start)


def drift(first: float, last: float) -> float:
    """Drift of a pose characteristic (ISO 9283 clause 7.7): ``|value(t_last) -
    value(t_first)|``, e.g. dAP from the AP of the first and the last cycle of a long run."""
    return abs(float(last) - float(first))
