"""The benchmark harness: timing helpers, result records, JSON output and the table.

Every case measures microcal against a baseline in the same run and reports the ratio, so
that a figure means the same on a slow and on a fast machine. Timings are never asserted.
"""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

RESULTS_DIR = Path(__file__).parent / "results"


@dataclass
class Case:
    """One measured case: microcal's figure, the baseline's, and a goal."""

    name: str
    unit: str  # of value and baseline, e.g. "points/s"
    value: float
    baseline_name: str
    baseline: float
    goal: str = ""  # the target in words, e.g. ">= 50x and >= 3e6 points/s"
    meets_goal: bool | None = None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def ratio(self) -> float:
        """value / baseline (for rates: how many times faster)."""
        return self.value / self.baseline if self.baseline else float("nan")


def best_time_s(fn: Callable[[], object], repeat: int = 3) -> float:
    """Best wall time of ``repeat`` calls, seconds (the least disturbed run)."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def machine() -> dict[str, Any]:
    """What the figures were measured on."""
    import numpy

    return {
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "machine": platform.machine(),
        "processor": _cpu_model() or platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "commit": _commit(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _cpu_model() -> str:
    """The processor's model name (Linux), or empty."""
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ""


def _commit() -> str:
    """The commit of the code measured (with ``+changes`` when the tree differs), or empty."""
    import subprocess

    repo = Path(__file__).resolve().parents[1]
    try:
        git = ["git", "-C", str(repo)]
        head = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()  # fmt: skip
        dirty = subprocess.run([*git, "status", "--porcelain", "src"], capture_output=True,
                               text=True, check=True).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return ""
    return head + ("+changes" if dirty else "")


def write_results(module: str, cases: list[Case]) -> Path:
    """Write ``results/<module>.json`` atomically and return its path."""
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{module}.json"
    payload = {
        "benchmark": module,
        "machine": machine(),
        "cases": [asdict(c) | {"ratio": c.ratio} for c in cases],
    }
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
    tmp.replace(path)
    return path
