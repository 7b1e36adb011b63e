"""Shared fixtures: seeded generators and camera pairs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import settings

from microcal.synthetic import thesis_cameras

settings.register_profile("ci", max_examples=200, deadline=None, derandomize=True)
settings.register_profile("dev", max_examples=60, deadline=None)
settings.load_profile("ci" if __import__("os").environ.get("CI") else "dev")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20121)


@pytest.fixture(scope="session")
def thesis_pair():
    return thesis_cameras()


def run_microcal(*args: object, cwd=None) -> subprocess.CompletedProcess[str]:
    """Run ``python -m microcal ARGS`` as a user would: no standard input, output captured."""
    return subprocess.run([sys.executable, "-m", "microcal", *map(str, args)], capture_output=True,
                          text=True, check=False, stdin=subprocess.DEVNULL, cwd=cwd)  # fmt: skip
