"""microcal._parallel.Background: one computation in a forked process, its result or its error here."""

from __future__ import annotations

import numpy as np
import pytest

from microcal._parallel import Background
from microcal.errors import InputError


def test_the_result_is_the_one_computed_here():
    data = np.random.default_rng(3).normal(size=(200, 3))  # a closure over memory
    job = Background(lambda: np.linalg.svd(data, compute_uv=False))
    np.testing.assert_array_equal(job.result(), np.linalg.svd(data, compute_uv=False))


def test_an_error_in_the_background_is_raised_by_result():
    def fails() -> None:
        raise InputError("steps: expected at least 3 views")

    with pytest.raises(InputError, match="at least 3 views"):
        Background(fails).result()


def test_a_result_not_wanted_is_cancelled():
    job = Background(lambda: sum(range(10**9)))
    job.cancel()
    job.cancel()  # twice is harmless


def test_done_once_the_result_is_there():
    import time

    job = Background(lambda: 42)
    for _ in range(500):  # at most 5 s
        if job.done():
            break
        time.sleep(0.01)
    assert job.done()
    assert job.result() == 42
