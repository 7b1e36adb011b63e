"""Run every benchmark module, write ``benchmarks/results/*.json`` and print a table.

Usage: ``python -m benchmarks [NAME ...]`` (names without the ``bench_`` prefix).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

from .harness import Case, write_results


def main(argv: list[str]) -> int:
    here = Path(__file__).parent
    names = sorted(p.stem for p in here.glob("bench_*.py"))
    wanted = [f"bench_{a.removeprefix('bench_')}" for a in argv]
    unknown = sorted(set(wanted) - set(names))
    if unknown:
        print(f"unknown benchmark(s) {unknown}; available: {names}", file=sys.stderr)
        return 2
    console = Console(width=max(Console().width, 110))
    table = Table(title="microcal benchmarks")
    for col in ("case", "microcal", "baseline", "ratio", "goal", "met"):
        table.add_column(
            col, justify="right" if col in ("microcal", "baseline", "ratio") else "left"
        )
    for name in wanted or names:
        console.print(f"running {name} ...")
        module = importlib.import_module(f"benchmarks.{name}")
        cases: list[Case] = module.run()
        path = write_results(name, cases)
        console.print(f"  wrote {path}")
        for c in cases:
            met = {None: "-", True: "yes", False: "NO"}[c.meets_goal]
            table.add_row(
                c.name,
                f"{c.value:.4g} {c.unit}",
                f"{c.baseline:.4g} ({c.baseline_name})",
                f"{c.ratio:.1f}x",
                c.goal,
                met,
            )
    console.print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
