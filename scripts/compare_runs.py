"""Compare the JSON files of two run directories number for number.

    python scripts/compare_runs.py OLD_DIR NEW_DIR [--rtol 1e-9]

Compares results.json, calibration.json and cameras.json: every number present in both files
must agree within ``rtol`` (relative, with an absolute floor of ``rtol`` for values near
zero); keys present in only one file are listed. Provenance and timing (which say when and
how long, not what) are skipped. Exit code 0 when every shared number agrees, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

FILES = ("results.json", "calibration.json", "cameras.json")
SKIP = {"provenance", "timing"}


def compare(a: Any, b: Any, path: str, rtol: float, out: dict[str, list[str]]) -> int:
    """Numbers compared; differences, and keys found on one side only, are added to ``out``."""
    if isinstance(a, dict) and isinstance(b, dict):
        n = 0
        for key in sorted(set(a) | set(b)):
            if key in SKIP:
                continue
            where = f"{path}.{key}"
            if key not in b:
                out["only_old"].append(where)
            elif key not in a:
                out["only_new"].append(where)
            else:
                n += compare(a[key], b[key], where, rtol, out)
        return n
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out["differ"].append(f"{path}: {len(a)} items vs {len(b)}")
            return 0
        pairs = enumerate(zip(a, b, strict=True))
        return sum(compare(x, y, f"{path}[{i}]", rtol, out) for i, (x, y) in pairs)
    if isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str):
        if a != b:
            out["differ"].append(f"{path}: {a!r} vs {b!r}")
        return 0
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if not (math.isclose(a, b, rel_tol=rtol, abs_tol=rtol) or (a != a and b != b)):
            out["differ"].append(f"{path}: {a!r} vs {b!r}")
        return 1
    if a != b:
        out["differ"].append(f"{path}: {a!r} vs {b!r}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--rtol", type=float, default=1e-9)
    args = parser.parse_args()
    ok = True
    for name in FILES:
        old, new = args.old / name, args.new / name
        if not old.exists() or not new.exists():
            print(f"{name}: missing in {'old' if not old.exists() else 'new'}")
            ok = False
            continue
        out: dict[str, list[str]] = {"differ": [], "only_old": [], "only_new": []}
        n = compare(json.loads(old.read_text()), json.loads(new.read_text()), name, args.rtol, out)
        print(f"{name}: {n} numbers compared, {len(out['differ'])} differ; keys only in old "
              f"{len(out['only_old'])}, only in new {len(out['only_new'])}")  # fmt: skip
        for kind in ("differ", "only_old", "only_new"):
            for line in out[kind][:20]:
                print(f"  {kind}: {line}")
        ok = ok and not out["differ"] and not out["only_old"]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
