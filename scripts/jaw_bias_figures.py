"""The jaw's tip on the thesis's cameras: bias and scatter of each detector along and across.

The ``thesis-gripper`` jaw (``tip:jaw:30:40``) rendered alone over the grey background with
each camera's model (22 µm pixels, lens distortion) and its focus blur (1.7 px), then
exposed as the simulator does (13 DN of noise on 76, 8 bits), with the noise cut at 0 (no
black level, as the simulator's frames) or kept. For each camera, per frame:

- ``apex (model fit)``: :func:`~microcal.vision.tip.detect_tip`'s apex against the true tip
  point's image;
- ``vertex (edges)``: :func:`~microcal.vision.tip_wedge.fit_wedge`'s vertex against the
  taper's true vertex's image (ideal pixels).

Printed: the mean error along the image axis (towards the shank) and across it, its
standard error, and the scatter of one frame, px.

Usage::

    python scripts/jaw_bias_figures.py --frames 20 --seed 0
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from microcal.sim import platform
from microcal.sim.tool_render import render_tool_region, tool_roi
from microcal.vision.tip import detect_tip
from microcal.vision.tip_target import parse_tip
from microcal.vision.tip_wedge import fit_wedge

JAW = parse_tip("tip:jaw:30:40")
BLUR_PX, LEVEL_DN, NOISE_DN = 1.7, 76.0, 12.8


def _light(camera, jaw):
    w, h = camera.image_size_px
    roi = tool_roi(camera, jaw, 4 * BLUR_PX + 3)
    x0, y0, x1, y1 = roi
    _, opacity = render_tool_region(camera, jaw, roi, supersample=2)
    light = np.full((h, w), LEVEL_DN, dtype=np.float32)
    light[y0:y1, x0:x1] *= 1.0 - opacity
    return cv2.GaussianBlur(light, (0, 0), BLUR_PX)


def _split(e: np.ndarray, axis: np.ndarray) -> tuple[float, float]:
    return float(e @ axis), float(e[0] * axis[1] - e[1] * axis[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    plat = platform("thesis-gripper", seed=args.seed)
    m, clock = plat.manipulator, plat.clock
    m.move_to_um([3500.0, 4200.0, 2600.0])
    m.wait_until_stopped(clock)
    assert plat.scene.carried is not None
    jaw = plat.scene.carried.at(plat.scene.board_placement(clock.now_s()))
    rng = np.random.default_rng(args.seed)
    print(f"thesis-gripper seed {args.seed}, {JAW.spec}, {args.frames} noisy frames per case")
    print("| camera | detector | noise | along (px) | across (px) | one frame's std along (px) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, camera in plat.camera_models.items():
        light = _light(camera, jaw)
        tip_px = camera.project(jaw.tip_um[None])[0]
        vertex_px = camera.project(jaw.vertex_um[None], distort=False)[0]
        first = detect_tip(light, JAW)
        cases = {"none": [light]}
        noise = [rng.standard_normal(light.shape).astype(np.float32) * NOISE_DN
                 for _ in range(args.frames)]  # fmt: skip
        cases["cut at 0"] = [np.clip(np.rint(light + n), 0, 255).astype(np.uint8) for n in noise]
        cases["kept"] = [light + n for n in noise]
        for label, frames in cases.items():
            apex, vertex = [], []
            for image in frames:
                det = detect_tip(image, JAW)
                if det.found:
                    apex.append(_split(det.apex_px - tip_px, det.axis))
                fit = fit_wedge(image, camera, first, end_px=3.4)
                if not isinstance(fit, str):
                    vertex.append(_split(fit.vertex_px - vertex_px, fit.axis))
            for detector, rows in (("apex (model fit)", apex), ("vertex (edges)", vertex)):
                r = np.array(rows).reshape(-1, 2)
                se = r.std(axis=0) / np.sqrt(max(len(r), 1))
                print(f"| {name} | {detector} | {label} | {r[:, 0].mean():+.4f} ± {se[0]:.4f} "
                      f"| {r[:, 1].mean():+.4f} ± {se[1]:.4f} | {r[:, 0].std():.3f} |")  # fmt: skip


if __name__ == "__main__":
    main()
