"""Running ``microcal`` as a user would, in its own process."""

from __future__ import annotations

import subprocess
import sys


def run_microcal(*args: object, cwd=None) -> subprocess.CompletedProcess[str]:
    """Run ``python -m microcal ARGS`` as a user would: no standard input, output captured."""
    return subprocess.run([sys.executable, "-m", "microcal", *map(str, args)], capture_output=True,
                          text=True, check=False, stdin=subprocess.DEVNULL, cwd=cwd)  # fmt: skip
