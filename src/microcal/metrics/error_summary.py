"""Summary figures of a set of non-negative errors (reprojection in px, prediction in µm)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import as_array
from ..errors import InputError

__all__ = ["ErrorSummary", "summarize_errors"]


@dataclass(frozen=True)
class ErrorSummary:
    """Summary figures of per-point errors, in the errors' unit.

    ``std`` is the sample standard deviation (N - 1 in the denominator, as MATLAB's ``std``
    that the thesis used); 0 for a single value.
    """

    n: int
    mean: float
    std: float
    rms: float
    median: float
    p95: float
    max: float

    def as_dict(self, suffix: str = "") -> dict[str, float | int]:
        """The figures as a plain dict, each key but ``n`` with ``suffix`` appended (``_um``)."""
        return {(k if k == "n" else k + suffix): v for k, v in asdict(self).items()}


def summarize_errors(errors: ArrayLike) -> ErrorSummary:
    """Mean, std, RMS, median, 95th percentile and maximum of per-point errors.

    Parameters
    ----------
    errors : (N,) float
        N >= 1 finite values.
    """
    e = as_array(errors, "errors", (None,))
    if e.size == 0:
        raise InputError("errors: expected at least one value, got none")
    return ErrorSummary(
        n=int(e.size),
        mean=float(e.mean()),
        std=float(e.std(ddof=1)) if e.size > 1 else 0.0,
        rms=float(np.sqrt(np.mean(e**2))),
        median=float(np.median(e)),
        p95=float(np.percentile(e, 95)),
        max=float(e.max()),
    )
