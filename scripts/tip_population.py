"""The tip detection over a population of rendered tools: the table of docs/vision.md.

Run from the repository root (a few minutes; heavy, so under the shared lock):

    flock /tmp/microcal-heavy.lock .venv/bin/python scripts/tip_population.py

Each image is drawn by :func:`microcal.sim.tool_population.draw_tool_image` from its seed (a
pipette, a needle or a jaw; taper 5-15 degrees; 0-25 degrees off the image plane; plain,
tissue or debris backgrounds under uneven light; focus 0, 1 or 2 depths of field off). The
fast fit (the default for every tool) is run on ``--fast-images`` images per row (40 by
default: 360 images), the image fit on every image of the other rows, the model fit on
the needles and jaws; the reference method on fewer (each needs its
own frames: the same tool 10 µm away, the focus stepped from -2 to +2 depths of field, the
tip located by the default method in the frame in focus). ``--images N`` sets the images per
row (25 by default). "covered" is the share of the found tips whose error ``e`` is within the 95 %
ellipse of the reported covariance ``C`` (``e^T C^-1 e <= 5.99``).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from typing import Any

import numpy as np

from microcal.sim.tool_population import (
    NUMERICAL_APERTURE,
    UM_PER_PX,
    Case,
    PopulationImage,
    draw_tool_image,
    population_camera,
)
from microcal.sim.tools import Optics, ToolPlacement, ToolScene, tool_image
from microcal.vision.tip import TipDetection, detect_tip
from microcal.vision.tip_reference import build_reference, match_tip
from microcal.vision.tip_target import parse_tip

KINDS = ("pipette", "needle", "jaw")


def _reference_detect(
    seed: int, kind: str, focus_dof: float
) -> tuple[TipDetection, PopulationImage, float]:
    image = draw_tool_image(seed, kind, focus_dof)
    placement = image.scene.placements[0]
    moved = ToolPlacement(placement.tool, placement.tip_um + [10.0, -6.0, 0.0], placement.axis)
    dof = Optics(NUMERICAL_APERTURE).depth_of_field_um(UM_PER_PX)
    offsets = np.linspace(-2.0, 2.0, 9) * dof
    rng = np.random.default_rng(seed + 1)
    frames = []
    for f in offsets:
        optics = Optics(NUMERICAL_APERTURE, focus_depth_um=1000.0 + f)
        scene = ToolScene([moved], optics, image.scene.background)
        frames.append(tool_image(population_camera(), scene, rng)[0])
    anchor = detect_tip(frames[4], parse_tip(image.spec))
    if not anchor.found:
        return TipDetection.none(f"reference: {anchor.reason}", "reference"), image, 0.0
    reference = build_reference(frames, offsets, anchor.apex_px)
    t0 = time.perf_counter()
    det = match_tip(image.image, reference)
    return det, image, time.perf_counter() - t0


def _row(method: str, kind: str, focus: float, results: list[tuple[Any, Any, float]]) -> str:
    found = [(d, im) for d, im, _ in results if d.found]
    times = [t for *_, t in results]
    if not found:
        return f"| {method} | {kind} | {focus:g} | {len(results)} | 0 | | | | | | | |"
    e = np.array([d.apex_px - im.truths[0].tip_px for d, im in found])
    axes = np.array([im.truths[0].axis_px for _, im in found])
    along = np.sum(e * axes, axis=1)
    across = e[:, 0] * -axes[:, 1] + e[:, 1] * axes[:, 0]
    bias = e.mean(axis=0)
    scatter = float(np.sqrt(np.mean(np.sum((e - bias) ** 2, axis=1)) / 2))
    p95 = float(np.percentile(np.hypot(e[:, 0], e[:, 1]), 95))
    sigma = float(np.median([d.std_px for d, _ in found]))
    chi2 = [float(ei @ np.linalg.solve(d.cov_px, ei)) for ei, (d, _) in zip(e, found, strict=True)]
    covered = float(np.mean(np.array(chi2) <= 5.99))
    return (
        f"| {method} | {kind} | {focus:g} | {len(results)} | {len(found)} | "
        f"{np.hypot(*bias):.3f} | {along.mean():+.3f} / {across.mean():+.3f} | {scatter:.3f} | "
        f"{p95:.2f} | {sigma:.3f} | {100 * covered:.0f} % | "
        f"{1000 * float(np.median(times)):.0f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=25, help="images per row")
    parser.add_argument("--fast-images", type=int, default=40, help="images per fast fit row")
    parser.add_argument("--methods", default="fast fit,image fit,model fit,reference",
                        help="the methods' rows, comma-separated")  # fmt: skip
    parser.add_argument("--reference-images", type=int, default=10)
    parser.add_argument("--empty", type=int, default=100, help="images without a tool")
    args = parser.parse_args()
    rows = []
    reasons: Counter[str] = Counter()
    methods = [m.strip() for m in args.methods.split(",")]
    for method in [m for m in ("fast fit", "image fit", "model fit") if m in methods]:
        for kind in KINDS if method != "model fit" else KINDS[1:]:
            for focus in (0.0, 1.0, 2.0):
                results = []
                for i in range(args.fast_images if method == "fast fit" else args.images):
                    seed = 10_000 * (1 + KINDS.index(kind)) + 100 * int(focus) + i
                    image = draw_tool_image(seed, kind, focus)
                    t0 = time.perf_counter()
                    det = detect_tip(image.image, parse_tip(image.spec), method=method)
                    results.append((det, image, time.perf_counter() - t0))
                    if not det.found:
                        why = det.reason.split(" (")[0]
                        reasons[f"{method}, {kind}, {focus:g} DOF: {why}"] += 1
                rows.append(_row(method, kind, focus, results))
    for kind in KINDS if "reference" in methods else ():
        for focus in (0.0, 1.0):
            results = []
            for i in range(args.reference_images):
                seed = 50_000 + 10_000 * KINDS.index(kind) + 100 * int(focus) + i
                det, image, seconds = _reference_detect(seed, kind, focus)
                results.append((det, image, seconds))
                if not det.found:
                    reasons[f"reference, {kind}, {focus:g} DOF: {det.reason.split(' (')[0]}"] += 1
            rows.append(_row("reference", kind, focus, results))
    refusals: Counter[str] = Counter()
    false_tips = 0
    cases: tuple[tuple[Case, int], ...] = (("none", args.empty), ("two", 20), ("outside", 20))
    for case, n in cases:
        for i in range(n):
            image = draw_tool_image(90_000 + i, KINDS[i % 3], 0.0, case)
            det = detect_tip(image.image, parse_tip(f"tip:{KINDS[i % 3]}"))
            if det.found:
                false_tips += case == "none"
                refusals[f"{case}: found a tip"] += 1
            else:
                refusals[f"{case}: {det.reason.split(' (')[0]}"] += 1
    print("| method | tool | focus (DOF) | images | found | bias (px) | along / across (px) | "
          "scatter (px) | 95 % error (px) | reported sigma (px) | covered | "
          "time (ms) |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))
    print()
    print(f"Images without a tool: {args.empty}, tips found in them: {false_tips}.")
    print()
    for key, count in sorted(refusals.items()):
        print(f"- {key}: {count}")
    for key, count in sorted(reasons.items()):
        print(f"- {key}: {count}")


if __name__ == "__main__":
    main()
