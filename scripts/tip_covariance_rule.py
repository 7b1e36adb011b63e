"""The fast fit's covariance scale, derived on one set of seeds: what makes its 95 % ellipse
hold 95 % of the errors.

Run from the repository root (a minute or so):

    .venv/bin/python scripts/tip_covariance_rule.py

Each image is drawn by :func:`microcal.sim.tool_population.draw_tool_image` from seeds
600_000 and up (not those of ``scripts/tip_population.py``, which checks the rule on its own
seeds), for each tool and focus offset (0 and 1 depth of field); the fast fit is run with
its covariance scale set to 1 and ``e^T C^-1 e`` is collected for every tip found. The rule
is one factor over all rows: the 95th percentile of ``e^T C^-1 e`` over 5.99 (the 95 % point
of a chi-square of two degrees of freedom). It prints each row's 95th percentile and the
factor; ``microcal.vision.tip_fast.COVARIANCE_SCALE`` holds the factor.
"""

from __future__ import annotations

import argparse

import numpy as np

import microcal.vision.tip_fast as tip_fast
from microcal.sim.tool_population import draw_tool_image
from microcal.vision.tip import detect_tip
from microcal.vision.tip_target import parse_tip

KINDS = ("pipette", "needle", "jaw")
CHI2_95 = 5.991


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=30, help="images per row")
    args = parser.parse_args()
    tip_fast.COVARIANCE_SCALE = 1.0
    everything = []
    for kind in KINDS:
        for focus in (0.0, 1.0):
            chi2 = []
            for i in range(args.images):
                seed = 600_000 + 10_000 * KINDS.index(kind) + 1000 * int(focus) + i
                image = draw_tool_image(seed, kind, focus)
                det = detect_tip(image.image, parse_tip(image.spec), method="fast fit")
                if det.found:
                    e = det.apex_px - image.truths[0].tip_px
                    chi2.append(float(e @ np.linalg.solve(det.cov_px, e)))
            everything += chi2
            q = float(np.percentile(chi2, 95))
            print(f"{kind:8s} {focus:g} DOF: {len(chi2)} found, 95th percentile of e'C^-1e "
                  f"{q:.2f} (factor {q / CHI2_95:.2f})")  # fmt: skip
    factor = float(np.percentile(everything, 95)) / CHI2_95
    print(f"all: factor {factor:.2f}")


if __name__ == "__main__":
    main()
