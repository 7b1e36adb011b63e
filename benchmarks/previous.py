"""The previous code as a baseline in the same run, where there is no outside one.

A benchmark module that has one defines ``measure() -> dict[str, float]``: its timings with
whichever ``microcal`` is importable. :func:`measure_previous` extracts the package as it was
at :data:`PREVIOUS_REF` (``git archive``) into a temporary directory and calls the module's
``measure`` in a child process whose ``microcal`` is that one, so that both versions run on
the same machine, minutes apart. ``MICROCAL_BENCH_PREVIOUS`` (a commit, tag or branch)
chooses another reference; ``none`` leaves the previous code out.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["PREVIOUS_REF", "measure_previous", "previous_ref"]

#: The code before the rendering, demo and compensator were made faster.
PREVIOUS_REF = "a22d18c4e483d496d54f71c117b5b80a77d96586"
REPO = Path(__file__).resolve().parents[1]


def previous_ref() -> str:
    """The reference the previous code is taken from (``none``: no previous code)."""
    return os.environ.get("MICROCAL_BENCH_PREVIOUS", PREVIOUS_REF)


def measure_previous(module: str, timeout_s: float = 1800.0) -> dict[str, float] | None:
    """``benchmarks.<module>.measure()`` run against the previous code; None when that code
    cannot be had (no git, no such commit) or the reference is ``none``."""
    ref = previous_ref()
    if ref == "none":
        return None
    with tempfile.TemporaryDirectory(prefix="microcal-previous-") as tmp:
        archive = subprocess.run(
            ["git", "-C", str(REPO), "archive", "--format=tar", ref, "src/microcal"],
            capture_output=True,
            check=False,
        )
        if archive.returncode != 0:
            print(f"  previous code {ref}: not available ({archive.stderr.decode().strip()})")
            return None
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(tmp) / "src"), str(REPO)]))
        code = (
            "import json, importlib, microcal; "
            f"m = importlib.import_module('benchmarks.{module}'); "
            "print('RESULT ' + json.dumps(m.measure()))"
        )
        done = subprocess.run(
            [sys.executable, "-c", code],
            env=env,
            cwd=tmp,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            check=False,
        )
        lines = [ln for ln in done.stdout.splitlines() if ln.startswith("RESULT ")]
        if done.returncode != 0 or not lines:
            print(f"  previous code {ref}: failed\n{done.stderr[-2000:]}")
            return None
        out: dict[str, float] = json.loads(lines[-1].removeprefix("RESULT "))
        return out
