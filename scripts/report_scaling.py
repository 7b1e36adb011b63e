"""Time the report and measure its page on large inputs: many cameras, a long journal.

    python scripts/report_scaling.py [--cameras 10 100 400] [--journal 10000 100000 1000000]

For each camera count N it writes a run directory holding only a cameras.json of N cameras
(each with per-view RMS, residuals, a lens model and an uncertainty map, as stereo-calibrate
writes them); for each journal length L a run directory holding only a journal.jsonl of L
poses, every other one failed. It builds the report of each and prints the seconds it took
(wall clock and CPU) and the size of the page. Inputs are written under a temporary
directory and removed.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def camera(k: int, n: int, rng: np.random.Generator) -> dict[str, object]:
    """One pinhole camera of a ring of ``n``, looking at the origin, with its figures."""
    angle = 2 * np.pi * k / n
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, s, 0.0], [0.0, 0.0, -1.0], [-s, c, 0.0]])
    centre = np.array([c, s, 0.0]) * -60000.0
    t = -R @ centre
    views = [f"view{v:02d}.png" for v in range(10)]
    residuals = {
        v: np.column_stack(
            [rng.uniform(0, 1280, 48), rng.uniform(0, 1024, 48), rng.normal(0, 0.1, (48, 2))]
        )
        .round(4)
        .tolist()
        for v in views
    }
    return {
        "model": "pinhole",
        "image_size_px": [1280, 1024],
        "K": [[8000.0, 0.0, 640.0], [0.0, 8000.0, 512.0], [0.0, 0.0, 1.0]],
        "dist": [0.0, 0.0, 0.0, 0.0, 0.0],
        "R": R.tolist(),
        "t_um": t.tolist(),
        "rms_px": float(rng.uniform(0.05, 0.2)),
        "views_used": len(views),
        "views_rejected": [{"image": "view10.png", "reason": "too few corners"}],
        "per_view_rms_px": {v: float(rng.uniform(0.05, 0.2)) for v in views},
        "residuals_px": residuals,
        "lens_model": {"name": "k1", "reason": "the simplest within 5 %", "candidates": [
            {"name": "none", "n_free": 0, "train_rms_px": 0.2, "held_out_rms_px": 0.21},
            {"name": "k1", "n_free": 1, "train_rms_px": 0.1, "held_out_rms_px": 0.11}]},
        "diagnostics": {
            "uncertainty_px": {"centre": 0.02, "corners": 0.08},
            "uncertainty_map_px": rng.uniform(0.02, 0.08, (9, 11)).round(4).tolist(),
            "verdict": ["the corners of the image (few target points there)"],
        },
    }  # fmt: skip


def cameras_run(root: Path, n: int) -> Path:
    run = root / f"cameras-{n}"
    run.mkdir()
    rng = np.random.default_rng(0)
    data = {
        "format": "microcal.cameras/1",
        "cameras": {f"cam{k:03d}": camera(k, n, rng) for k in range(n)},
        "stereo": {"method": "known heights", "baseline_um": 60000.0, "angle_deg": 30.0},
    }
    (run / "cameras.json").write_text(json.dumps(data), encoding="utf-8")
    return run


def journal_run(root: Path, lines: int) -> Path:
    run = root / f"journal-{lines}"
    run.mkdir()
    with (run / "journal.jsonl").open("w", encoding="utf-8") as f:
        for pose in range(1, lines + 1):
            if pose % 2:
                record = {"pose": pose, "status": "ok", "settle_s": 0.5 + (pose % 7) * 0.1,
                          "images": {"top": {"file": f"images/top_{pose:07d}.tiff"}}}  # fmt: skip
            else:
                record = {"pose": pose, "status": "failed", "reason": "top: frame dropped"}
            f.write(json.dumps(record) + "\n")
    return run


def measure(run: Path) -> tuple[float, float, int]:
    """Wall and CPU seconds to build the report of ``run``, and the page's bytes."""
    from microcal.report import build_report

    start, cpu = time.perf_counter(), time.process_time()
    page = build_report(run)
    return time.perf_counter() - start, time.process_time() - cpu, len(page.encode("utf-8"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cameras", type=int, nargs="*", default=[10, 100, 400])
    parser.add_argument("--journal", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for n in args.cameras:
            wall, cpu, size = measure(cameras_run(root, n))
            print(f"cameras {n:>7}: {wall:7.1f} s ({cpu:7.1f} s CPU), page {size / 1e6:7.2f} MB",
                  flush=True)  # fmt: skip
        for lines in args.journal:
            wall, cpu, size = measure(journal_run(root, lines))
            print(f"journal {lines:>7}: {wall:7.1f} s ({cpu:7.1f} s CPU), "
                  f"page {size / 1e6:7.2f} MB", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
