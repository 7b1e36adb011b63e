"""Put the figures of ``make bench`` (benchmarks/results/*.json) into the README.

    python scripts/bench_readme.py [--write]

Prints the README's performance table, made from the result files alone: each case with
microcal's figure, its baseline measured in the same run, the ratio and the goal, and under
it the machine, the date and the commit of each file. ``--write`` replaces the table between
the README's ``<!-- bench:start -->`` and ``<!-- bench:end -->`` markers.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
START, END = "<!-- bench:start -->", "<!-- bench:end -->"


def _figure(value: float, unit: str) -> str:
    if not math.isfinite(value):
        return "-"
    return f"{value:.3g} {unit}"


def table(files: list[Path]) -> str:
    """The markdown table of the cases of ``files`` and the lines naming their machines."""
    rows = ["| case | microcal | baseline (same run) | ratio | goal | met |",
            "|---|---|---|---|---|---|"]  # fmt: skip
    machines = []
    for path in files:
        data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
        for c in data["cases"]:
            met = {None: "-", True: "yes", False: "no"}[c["meets_goal"]]
            baseline = f"{_figure(c['baseline'], c['unit'])} ({c['baseline_name']})"
            ratio = c["ratio"]
            ratio_text = f"{ratio:.2g}x" if ratio is not None and math.isfinite(ratio) else "-"
            rows.append(f"| {c['name']} | {_figure(c['value'], c['unit'])} | {baseline} | "
                        f"{ratio_text} | {c['goal']} | {met} |")  # fmt: skip
        m = data["machine"]
        load = m.get("load_average")
        load_text = f", load {load[0]:.1f}" if load else ""
        commit = (m.get("commit") or "")[:10]
        machines.append(f"`{data['benchmark']}`: {m['time'][:10]}, {m['processor']}, "
                        f"{m['cpus']} CPUs{load_text}, Python {m['python']}, numpy "
                        f"{m['numpy']}{', commit ' + commit if commit else ''}")  # fmt: skip
    return "\n".join(rows) + "\n\nMeasured by `make bench`: " + "; ".join(machines) + "."


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="replace the README's table")
    args = parser.parse_args()
    files = sorted(RESULTS.glob("*.json"))
    if not files:
        print("no benchmarks/results/*.json: run make bench first", file=sys.stderr)
        return 1
    text = table(files)
    if not args.write:
        print(text)
        return 0
    readme = ROOT / "README.md"
    body = readme.read_text(encoding="utf-8")
    if START not in body or END not in body:
        print(f"README.md: no {START} ... {END} markers", file=sys.stderr)
        return 1
    head, rest = body.split(START, 1)
    _, tail = rest.split(END, 1)
    readme.write_text(f"{head}{START}\n{text}\n{END}{tail}", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
