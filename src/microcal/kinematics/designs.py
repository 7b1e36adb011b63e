"""Command designs: the joint positions an acquisition visits (thesis 4.2, Fig 4.2).

- ``random``: uniform random positions over the travel (the thesis's design);
- ``sobol`` and ``lhs``: space-filling designs (scrambled Sobol, Latin hypercube; scipy's qmc);
- ``grid``: a regular grid with about the requested number of points;
- the evaluation trajectories: the poses of Table 5-2, the decoupling path of Fig 5.5 and the
  ISO 9283 cube (see :mod:`microcal.procedures.evaluation`).

Every design is reproducible from its seed and checked before anything moves: inside the
limits, finite, and able to identify a model (each axis moved over a real part of its range,
the axes not moved together).
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.stats.qmc as qmc
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, check_limits
from ..errors import DegenerateDataError, InputError

__all__ = ["DESIGNS", "check_design", "make_design"]

DESIGNS = ("random", "sobol", "lhs", "grid", "chebyshev")
#: An axis must span at least this share of its travel to be identified.
MIN_SPAN = 0.25
#: Two axes whose commands correlate this much cannot be told apart.
MAX_CORRELATION = 0.95


def make_design(
    kind: str, n: int, low_um: ArrayLike, high_um: ArrayLike, seed: int | np.random.Generator = 0
) -> FloatArray:
    """Joint commands of a design.

    Parameters
    ----------
    kind : {"random", "sobol", "lhs", "grid", "chebyshev"}
        ``chebyshev``: random, each axis drawn from the arcsine (Chebyshev) distribution
        of its travel, denser towards the ends: for a smooth model of high order, the
        design whose worst prediction variance over the travel is least (uniform draws
        leave the ends, where poses are also commanded, thinly covered).
    n : int
        Number of poses (a grid has the nearest number its shape allows).
    low_um, high_um : (k,) float
        The travel to cover, µm; an axis with low == high is held there (a two-axis
        positioner's z) and the design spans the others.
    seed : int or numpy.random.Generator
        A seed, or a generator to draw from (it advances).

    Returns
    -------
    d_um : (n, k) float
    """
    low = as_array(low_um, "low_um", (None,))
    high = as_array(high_um, "high_um", (low.size,))
    if np.any(high < low) or np.all(high == low):
        raise InputError(
            f"design: expected low < high on every axis (low == high on a held one), got "
            f"{low.tolist()} and {high.tolist()}"
        )
    if n < 2:
        raise InputError(f"poses: expected at least 2, got {n}")
    moving = high > low
    k = int(moving.sum())
    if kind == "random":
        unit = np.random.default_rng(seed).uniform(size=(n, k))
    elif kind == "sobol":
        with warnings.catch_warnings():  # balance is best at powers of 2; any n is still fine
            warnings.simplefilter("ignore", UserWarning)
            unit = qmc.Sobol(k, scramble=True, seed=seed).random(n)
    elif kind == "lhs":
        unit = qmc.LatinHypercube(k, seed=seed).random(n)
    elif kind == "chebyshev":
        u = np.random.default_rng(seed).uniform(size=(n, k))
        unit = 0.5 * (1.0 - np.cos(np.pi * u))
    elif kind == "grid":
        per_axis = max(2, round(n ** (1.0 / k)))
        axes = [np.linspace(0.0, 1.0, per_axis)] * k
        unit = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, k)
        # Visit the grid in a seeded random order: a fixed sweep would tie slow drift to
        # one corner of the workspace.
        unit = unit[np.random.default_rng(seed).permutation(len(unit))]
    else:
        raise InputError(f"design: expected one of {list(DESIGNS)} or a CSV file, got {kind!r}")
    out = np.broadcast_to(low, (unit.shape[0], low.size)).copy()
    out[:, moving] += unit * (high - low)[moving]
    return out


def check_design(
    d_um: ArrayLike, limits_um: ArrayLike, axes: tuple[str, ...] = ("x", "y", "z")
) -> FloatArray:
    """Refuse a design that leaves the limits or cannot identify the kinematics.

    Parameters
    ----------
    d_um : (N, k) float
    limits_um : (k, 2) float
        Soft limits (low, high) per axis.

    Raises
    ------
    LimitError
        A command outside the limits (naming the first).
    DegenerateDataError
        An axis that does not move over at least a quarter of its travel, or two axes always
        moved together (they could not be told apart).
    """
    d = as_array(d_um, "commands", (None, len(axes)))
    lim = as_array(limits_um, "limits_um", (len(axes), 2))
    check_limits(d, lim, axes=axes)
    moving = lim[:, 1] > lim[:, 0]  # a held axis (low == high) has only its one value
    span = np.ptp(d, axis=0) / np.where(moving, lim[:, 1] - lim[:, 0], 1.0)
    for k in np.flatnonzero(moving & (span < MIN_SPAN)).tolist():
        raise DegenerateDataError(
            f"the design moves axis {axes[k]} over {100 * span[k]:.0f} % of its travel; at least "
            f"{100 * MIN_SPAN:.0f} % is needed to identify it"
        )
    if len(d) >= 3:
        with np.errstate(invalid="ignore", divide="ignore"):
            corr: FloatArray = np.atleast_2d(np.corrcoef(d.T))
        for a in np.flatnonzero(moving).tolist():
            for b in np.flatnonzero(moving).tolist():
                if b > a and abs(corr[a, b]) > MAX_CORRELATION:
                    raise DegenerateDataError(
                        f"the design moves axes {axes[a]} and {axes[b]} together (correlation "
                        f"{corr[a, b]:.2f}); they cannot be told apart: use a random or "
                        f"space-filling design"
                    )
    return d
