"""The README's picture: the report's decoupling plots of a demo run, uncalibrated over optimal.

    python scripts/readme_figure.py RUN_DIR [--out docs/images/decoupling.png]

Reads RUN_DIR/results.json (written by ``microcal demo``, e.g. ``microcal demo --quick --out
RUN_DIR``) and draws the decoupling test without calibration and with the optimal
compensator, each with the report's own figure function, one above the other, into one PNG
(a palette image, to stay small in the repository).
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import sys
from pathlib import Path

import numpy as np
from matplotlib import image
from PIL import Image

from microcal.report import figures

CONDITIONS = ("uncalibrated", "optimal")
SOURCES = ("vision", "truth")
PALETTE = 64
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "docs" / "images" / "decoupling.png"


def decoupling_png(results: dict[str, object], condition: str) -> np.ndarray:
    """The report's decoupling figure of one condition, as an (H, W, 4) float image."""
    decoupling = results["decoupling"]
    assert isinstance(decoupling, dict)
    runs = {
        source: (
            np.asarray(decoupling[source][condition]["samples_um"], dtype=float),
            np.asarray(decoupling[source][condition]["segment"], dtype=int),
        )
        for source in SOURCES
        if decoupling.get(source, {}).get(condition, {}).get("samples_um")
    }
    if not runs:
        raise SystemExit(f"results.json holds no decoupling test of {condition}")
    uri = figures.decoupling(condition, runs)
    data = base64.b64decode(uri.split(",", 1)[1])
    return np.asarray(image.imread(io.BytesIO(data), format="png"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a demo's run directory")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="PNG to write")
    args = parser.parse_args()
    path = args.run / "results.json"
    if not path.is_file():
        print(f"readme_figure: {path} not found (run microcal demo first)", file=sys.stderr)
        return 2
    results = json.loads(path.read_text(encoding="utf-8"))
    if "decoupling" not in results:
        print(f"readme_figure: {path} holds no decoupling test", file=sys.stderr)
        return 2
    panels = [decoupling_png(results, condition) for condition in CONDITIONS]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.round(np.vstack(panels)[..., :3] * 255).astype(np.uint8)
    # a palette of 64 colours: the plots' few colours and their anti-aliasing, a quarter the size
    Image.fromarray(rgb).quantize(colors=PALETTE).save(args.out, format="png", optimize=True)
    print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
