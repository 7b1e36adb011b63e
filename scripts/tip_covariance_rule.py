"""The fast fit's covariance rule, derived on one set of seeds: what makes its 95 % ellipse
hold 90-98 % of the errors.

Run from the repository root (a minute or two):

    .venv/bin/python scripts/tip_covariance_rule.py

Each image is drawn by :func:`microcal.sim.tool_population.draw_tool_image` from seeds
600_000 and up (not those of ``scripts/tip_population.py``, which checks the rule on its own
seeds), ``--images`` per tool and focus offset (0, 1 and 2 depths of field); the fast fit is
run with the rule switched off (the fit's own covariance ``C``) and its error ``e`` kept. The
rule states ``f C + (m blur)^2 I``, the model's own error growing with the blur at the tip,
with ``m`` for glass and for an opaque tool; the grid's ``f`` and ``m`` that put the most
rows in focus and one depth of field off within 90-98 % (the share of ``e^T C'^-1 e <=
5.99``) are printed beside the stated ones
(``microcal.vision.tip_fast.COVARIANCE_SCALE`` and ``MODEL_ERROR_PER_BLUR``) and each row's
coverage under them.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

import microcal.vision.tip_fast as tip_fast
from microcal.sim.tool_population import draw_tool_image
from microcal.vision.tip import detect_tip
from microcal.vision.tip_target import parse_tip

KINDS = ("pipette", "needle", "jaw")
FOCI = (0.0, 1.0, 2.0)
CHI2_95 = 5.991


def _collect(n: int) -> dict[str, np.ndarray]:
    rows = []
    for kind in KINDS:
        for focus in FOCI:
            for i in range(n):
                seed = 600_000 + 10_000 * KINDS.index(kind) + 1000 * int(focus) + i
                image = draw_tool_image(seed, kind, focus)
                det = detect_tip(image.image, parse_tip(image.spec), method="fast fit")
                if det.found:
                    e = det.apex_px - image.truths[0].tip_px
                    rows.append([KINDS.index(kind), focus, *e, *det.cov_px.ravel(), det.blur_px])
    a = np.array(rows)
    return {"kind": a[:, 0].astype(int), "focus": a[:, 1], "e": a[:, 2:4],
            "cov": a[:, 4:8].reshape(-1, 2, 2), "blur": a[:, 8]}  # fmt: skip


def _coverage(d: dict[str, np.ndarray], f: float, m_glass: float, m_opaque: float) -> np.ndarray:
    """Each row's share (%) of errors within the 95 % ellipse, pipette/needle/jaw x focus."""
    m = np.where(d["kind"] == 0, m_glass, m_opaque) * d["blur"]
    cov = d["cov"] * f + (m**2)[:, None, None] * np.eye(2)
    e = d["e"]
    inside = np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e) <= CHI2_95
    return np.array([100 * inside[(d["kind"] == k) & (d["focus"] == f0)].mean()
                     for k in range(len(KINDS)) for f0 in FOCI])  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=40, help="images per row")
    args = parser.parse_args()
    stated = (tip_fast.COVARIANCE_SCALE, *tip_fast.MODEL_ERROR_PER_BLUR)
    tip_fast.COVARIANCE_SCALE, tip_fast.MODEL_ERROR_PER_BLUR = 1.0, (0.0, 0.0)
    data = _collect(args.images)
    tip_fast.COVARIANCE_SCALE, tip_fast.MODEL_ERROR_PER_BLUR = stated[0], stated[1:]
    near = [i for i in range(len(KINDS) * len(FOCI)) if FOCI[i % len(FOCI)] < 2.0]
    best = None
    grid = itertools.product([1.0, 1.5, 2.0, 3.0], [0.0, 0.1, 0.15, 0.2, 0.3],
                             [0.0, 0.03, 0.06, 0.1])  # fmt: skip
    for f, mg, mo in grid:
        c = _coverage(data, f, mg, mo)[near]
        miss = float(np.sum(np.maximum(90 - c, 0) + np.maximum(c - 98, 0)))
        if best is None or miss < best[0]:
            best = (miss, f, mg, mo)
    assert best is not None
    print(f"grid's best: f {best[1]:g}, m glass {best[2]:g}, m opaque {best[3]:g} "
          f"(outside 90-98 % by {best[0]:.0f} points in all)")  # fmt: skip
    print(f"stated: f {stated[0]:g}, m glass {stated[1]:g}, m opaque {stated[2]:g}")
    for name, rule in (("the fit's own", (1.0, 0.0, 0.0)), ("stated", stated)):
        c = _coverage(data, *rule)
        cells = ", ".join(f"{k} {f0:g} DOF {c[i]:.0f} %"
                          for i, (k, f0) in enumerate(itertools.product(KINDS, FOCI)))  # fmt: skip
        print(f"{name}: {cells}")


if __name__ == "__main__":
    main()
