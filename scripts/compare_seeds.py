"""Compare the demo's headline figures over several seeds, before and after a change.

    python scripts/compare_seeds.py OLD_TEMPLATE NEW_TEMPLATE [--seeds 0 1 2 3]

Each template names a demo directory with ``{seed}`` in it (``/tmp/old-{seed}``). For every
headline figure (stereo RMS, 3D error, validation mean of each model, AP by truth and by
vision per compensator, decoupling by truth and by vision per compensator) the script prints
the mean and the seed-to-seed standard deviation (n - 1) before and after, and whether the
new mean lies within one standard deviation of the old mean: the figures are then "the same
in distribution", which is what a change of the random stream (a rendering change) can
promise where it cannot promise the same numbers (``scripts/compare_runs.py``). Markdown on
standard output; exit code 0 when every figure is within, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from pathlib import Path
from typing import Any

CONDITIONS = ("uncalibrated", "matrix", "optimal")
SOURCES = ("truth", "vision")


def headline(run: Path) -> dict[str, float]:
    """The headline figures of one demo directory, by name."""
    results: dict[str, Any] = json.loads((run / "results.json").read_text(encoding="utf-8"))
    cameras: dict[str, Any] = json.loads((run / "cameras.json").read_text(encoding="utf-8"))
    out = {"stereo RMS px": float(cameras["stereo"]["rms_px"])}
    out["3D error RMS µm"] = float(results["measurement"]["rms_error_um"])
    for name, model in results["models"].items():
        out[f"validation mean µm ({name})"] = float(model["validation"]["mean_um"])
    for source in SOURCES:
        for condition in CONDITIONS:
            figures = results.get("pose_accuracy", {}).get(source, {}).get(condition)
            if figures is not None:
                out[f"AP mean µm, {source}, {condition}"] = float(figures["mean_ap_p_um"])
    for source in SOURCES:
        for condition in CONDITIONS:
            figures = results.get("decoupling", {}).get(source, {}).get(condition)
            if figures is not None:
                worst = max(max(abs(a), abs(b)) for a, b in figures["undesired_um"].values())
                out[f"decoupling worst µm, {source}, {condition}"] = float(worst)
    return out


def _stats(values: list[float]) -> tuple[float, float]:
    return statistics.fmean(values), statistics.stdev(values) if len(values) > 1 else math.nan


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", help="directory template with {seed}")
    parser.add_argument("new", help="directory template with {seed}")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    args = parser.parse_args()
    old = [headline(Path(args.old.format(seed=s))) for s in args.seeds]
    new = [headline(Path(args.new.format(seed=s))) for s in args.seeds]
    names = [n for n in old[0] if all(n in r for r in old + new)]
    seeds = ", ".join(str(s) for s in args.seeds)
    print(f"seeds {seeds}: mean ± seed-to-seed standard deviation\n")
    print("| figure | before | after | after - before, in SD of before | within 1 SD |")
    print("|---|---|---|---|---|")
    ok = True
    for name in names:
        m0, s0 = _stats([r[name] for r in old])
        m1, s1 = _stats([r[name] for r in new])
        z = (m1 - m0) / s0 if s0 > 0 else math.inf if m1 != m0 else 0.0
        within = abs(z) <= 1.0
        ok = ok and within
        print(f"| {name} | {m0:.4g} ± {s0:.2g} | {m1:.4g} ± {s1:.2g} | {z:+.2f} | "
              f"{'yes' if within else 'NO'} |")  # fmt: skip
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
