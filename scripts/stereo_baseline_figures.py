"""The Bumblebee2 stereo set's baseline against BoofCV's published calibration: the figures
of docs/vision.md ("On real photographs").

``../shared/data/boofcv_bumblebee2_chess`` (PROVENANCE.md: BoofCV's |T| = 120.051 mm in
OpenCV's convention) is calibrated through :func:`microcal.procedures.stereo.calibrate_views`
with the default settings (the automatic lens choice) and with each lens model named, then
with the default settings leaving out one pair at a time (the jackknife's standard
deviation of the baseline).

Usage: python scripts/stereo_baseline_figures.py [--no-jackknife]
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from microcal.procedures.stereo import calibrate_views
from microcal.vision.stereo_calibration import StereoCalibration
from microcal.vision.targets import parse_target

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "boofcv_bumblebee2_chess"
TARGET = "chessboard:6x4:30000"
#: BoofCV's baseline (PROVENANCE.md), µm.
BOOFCV_BASELINE_UM = 120_051.0


def calibrate(files: dict[str, list[Path]], lens_model: str = "auto") -> StereoCalibration:
    """One calibration of the pairs in ``files``."""
    return calibrate_views({c: [f.name for f in fs] for c, fs in files.items()},
                           lambda c, i: [cv2.imread(str(files[c][i]))], parse_target(TARGET),
                           lens_model=lens_model)  # fmt: skip


def main() -> None:
    files = {side: sorted(DATA.glob(f"{side}*.jpg")) for side in ("left", "right")}
    if not files["left"]:
        sys.exit(f"the Bumblebee2 photographs are not here ({DATA} is absent)")
    print("| lens model | models chosen | baseline, mm (from BoofCV's) | angle, deg | mono RMS, px "
          "| stereo RMS, px |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- |")
    for model in ("auto", "radial2", "radial2-tangential", "radial3-tangential"):
        cal = calibrate(files, model)
        error = 100.0 * (cal.baseline_um / BOOFCV_BASELINE_UM - 1.0)
        chosen = " / ".join(str(c.lens_model["name"]) for c in cal.cameras.values())
        mono = " / ".join(f"{c.rms_px:.4f}" for c in cal.cameras.values())
        print(f"| {model} | {chosen} | {cal.baseline_um / 1000:.3f} ({error:+.2f} %) "
              f"| {cal.angle_deg:.3f} | {mono} | {cal.rms_px:.4f} |")  # fmt: skip
    if "--no-jackknife" in sys.argv:
        return
    lengths = []
    for k in range(len(files["left"])):
        kept = {c: [f for i, f in enumerate(fs) if i != k] for c, fs in files.items()}
        lengths.append(calibrate(kept).baseline_um)
    b = np.array(lengths)
    sd = float(np.sqrt((len(b) - 1) / len(b) * np.sum((b - b.mean()) ** 2)))
    print(f"\njackknife over the {len(b)} pairs (default settings): baseline "
          f"{b.min() / 1000:.3f}-{b.max() / 1000:.3f} mm, standard deviation {sd / 1000:.3f} mm "
          f"({100.0 * sd / BOOFCV_BASELINE_UM:.2f} %)")  # fmt: skip


if __name__ == "__main__":
    main()
