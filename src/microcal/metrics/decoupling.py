"""The decoupling test of thesis 5.3.2 (Fig 5.5): motion along one axis at a time.

The manipulator moves along x, then y, then z. While one axis moves, the others should stay
still; their *undesired displacement* is how far they moved from where they were when that
segment began (thesis Fig 5.6-5.8, Table 5-5). The integration index Ω of Eq 5.3
integrates the magnitude of the undesired displacement over the samples (trapezoidal rule,
one sampling unit between samples; Table 5-6 reports it in µm x sampling unit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import InputError
from ..json_value import JsonValue

__all__ = ["DecouplingResult", "decoupling_metrics", "integration_index"]

AXES = ("x", "y", "z")


def integration_index(undesired_um: ArrayLike) -> float:
    """Ω of Eq 5.3: trapezoidal integral of ``|e|`` over samples one unit apart, µm x sample."""
    e = np.abs(as_array(undesired_um, "undesired_um", (None,)))
    if e.size < 2:
        return 0.0
    return float(np.sum((e[1:] + e[:-1]) / 2.0))


@dataclass(frozen=True)
class DecouplingResult:
    """Undesired displacements of each axis while the others moved."""

    undesired_um: dict[
        str, FloatArray
    ]  # per axis: its undesired displacement, samples of the other segments
    ranges_um: dict[str, tuple[float, float]]  # per axis: (min, max)
    omega: dict[str, float]  # per axis: Eq 5.3

    def as_dict(self) -> dict[str, JsonValue]:
        """The per-condition object of results.json."""
        return {
            "undesired_um": {a: list(self.ranges_um[a]) for a in AXES},
            "omega": dict(self.omega),
        }


def decoupling_metrics(measured_um: ArrayLike, segment: ArrayLike) -> DecouplingResult:
    """Undesired displacement ranges and Ω from a sampled decoupling run.

    Parameters
    ----------
    measured_um : (N, 3) float
        Measured positions along the path, µm, in sampling order.
    segment : (N,) int
        The axis moving at each sample (0 = x, 1 = y, 2 = z). The first sample of each
        segment is where that segment starts (normally the last pose of the previous one).

    Returns
    -------
    DecouplingResult
    """
    p = as_array(measured_um, "measured_um", (None, 3))
    seg = np.asarray(segment)
    if seg.shape != (p.shape[0],) or not np.isin(seg, (0, 1, 2)).all():
        raise InputError(f"segment: expected {p.shape[0]} values in 0, 1, 2, got shape {seg.shape}")
    undesired: dict[str, list[FloatArray]] = {a: [] for a in AXES}
    for moving in (0, 1, 2):
        idx = np.flatnonzero(seg == moving)
        if idx.size == 0:
            continue
        start = p[idx[0]]
        for axis in range(3):
            if axis != moving:
                undesired[AXES[axis]].append(p[idx, axis] - start[axis])
    out = {a: np.concatenate(v) if v else np.zeros(0) for a, v in undesired.items()}
    ranges = {a: (float(v.min()), float(v.max())) if v.size else (0.0, 0.0) for a, v in out.items()}
    # Ω per axis: the integral over each segment in which the axis is still, summed.
    omega = {}
    for axis in range(3):
        total = 0.0
        for moving in (0, 1, 2):
            idx = np.flatnonzero(seg == moving)
            if moving != axis and idx.size:
                total += integration_index(p[idx, axis] - p[idx[0], axis])
        omega[AXES[axis]] = total
    return DecouplingResult(out, ranges, omega)
