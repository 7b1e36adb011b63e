"""Corner refinement against OpenCV's ``cornerSubPix`` at its best half-window, on real and
derived sets: the table of docs/vision.md ("Sub-pixel corners").

For every set, camera by camera: the chessboard is found in each image by OpenCV
(``findChessboardCorners``, else ``findChessboardCornersSB``) and refined by ``cornerSubPix``
with each half-window 2..8 (EPS + COUNT 30 / 0.001); microcal detects it with
:func:`microcal.vision.detect.detect`. Both sets of corners are calibrated by
``cv2.calibrateCamera`` with OpenCV's default lens model on the views both found, and the
table gives the mono RMS (px) of OpenCV's best half-window and of microcal. On rendered
views (``sim.calibration_views``) the corners' RMS error against the truth is given as well.

Derived sets: the real photographs scaled down (area-averaged) so the squares shrink to
webcam sizes, and recompressed as JPEG at the stated quality.

Usage: python scripts/corner_figures.py [--quick]   (prints a Markdown table)
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from microcal.sim.calibration_views import render_calibration_views, wide_angle_camera
from microcal.vision.detect import detect
from microcal.vision.targets import parse_target

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.001)
HALF_WINDOWS = range(2, 9)

SETS = {
    "Bumblebee2": ("boofcv_bumblebee2_chess", ("left", "right"), (6, 4), "{cam}*.jpg"),
    "trinocular ECoCheck": ("boofcv_trinocular_ecocheck", ("left", "middle", "right"), (13, 9),
                            "{cam}/{cam}*.jpg"),
}  # fmt: skip


def _transform(scale: float, quality: int | None) -> Callable[[np.ndarray], np.ndarray]:
    def apply(gray: np.ndarray) -> np.ndarray:
        out = gray
        if scale != 1.0:
            out = cv2.resize(out, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        if quality is not None:
            _, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, quality])
            out = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
        return out

    return apply


def _opencv_corners(gray: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    ok, c = cv2.findChessboardCorners(gray, size)
    if not ok:
        ok, c = cv2.findChessboardCornersSB(gray, size)
    return c.reshape(-1, 1, 2).astype(np.float32) if ok else None


def compare(grays: list[np.ndarray], size: tuple[int, int], truth: list[np.ndarray] | None = None
            ) -> dict[str, float]:  # fmt: skip
    """Mono RMS (and truth error) of OpenCV's best half-window and of microcal, px."""
    target = parse_target(f"chessboard:{size[0]}x{size[1]}:1000")
    obj = target.points_um().astype(np.float32)
    raw = [_opencv_corners(g, size) for g in grays]
    dets = [detect(g, target) for g in grays]
    views = [i for i in range(len(grays)) if raw[i] is not None and dets[i].found]
    shape = grays[0].shape[::-1]

    def rms(corners: list[np.ndarray], ids: list[np.ndarray]) -> float:
        return float(cv2.calibrateCamera([obj[k] for k in ids], corners, shape, None, None)[0])

    def off(q: np.ndarray, i: int) -> np.ndarray:
        assert truth is not None
        t = truth[i]
        return min((q - t, q - t[::-1]), key=lambda d: float(np.sum(d**2)))

    out: dict[str, float] = {"views": len(views)}
    best = (np.inf, 0, np.nan)
    all_ids = [np.arange(len(obj))] * len(views)
    for h in HALF_WINDOWS:
        cs = [cv2.cornerSubPix(grays[i], raw[i].copy(), (h, h), (-1, -1), CRITERIA) for i in views]
        r = rms(cs, all_ids)
        if r < best[0]:
            err = np.nan
            if truth is not None:
                err = float(
                    np.sqrt(
                        np.mean(
                            np.concatenate(
                                [
                                    np.sum(off(c.reshape(-1, 2), i) ** 2, axis=1)
                                    for c, i in zip(cs, views, strict=True)
                                ]
                            )
                        )
                    )
                )
            best = (r, h, err)
    out["opencv_rms_px"], out["opencv_half"], out["opencv_truth_px"] = best
    ours = [dets[i].q_px.astype(np.float32) for i in views]
    out["microcal_rms_px"] = rms(ours, [dets[i].ids for i in views])
    if truth is not None:
        out["microcal_truth_px"] = float(np.sqrt(np.mean(np.concatenate(
            [np.sum(off(dets[i].q_px, i) ** 2, axis=1) for i in views]))))  # fmt: skip
    return out


def real_rows(quick: bool) -> list[tuple[str, dict[str, float]]]:
    rows = []
    variants = [(1.0, None), (0.5, 75), (0.4, 60)] if not quick else [(1.0, None), (0.5, 75)]
    for name, (folder, cams, size, pattern) in SETS.items():
        root = DATA / folder
        if not root.is_dir():
            continue
        for scale, quality in variants:
            apply = _transform(scale, quality)
            for cam in cams:
                files = sorted(root.glob(pattern.format(cam=cam)))
                grays = [apply(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)) for f in files]
                label = f"{name} {cam}" + ("" if scale == 1.0 else f", x{scale} JPEG {quality}")
                rows.append((label, compare(grays, size)))
                print(label, rows[-1][1], file=sys.stderr, flush=True)
    return rows


def rendered_rows(quick: bool) -> list[tuple[str, dict[str, float]]]:
    rows = []
    target = parse_target("chessboard:9x6:20000")
    cam = wide_angle_camera()
    for blur, quality in [(0.7, None), (1.5, None), (0.7, 70), (1.5, 50)][: 2 if quick else 4]:
        views = render_calibration_views(cam, target, 12, seed=3, blur_sigma_px=blur)
        apply = _transform(1.0, quality)
        grays = [apply(np.asarray(im)) for im in views.images]
        label = f"rendered 9x6, blur {blur} px" + ("" if quality is None else f", JPEG {quality}")
        rows.append((label, compare(grays, (9, 6), [np.asarray(c) for c in views.corners_px])))
        print(label, rows[-1][1], file=sys.stderr, flush=True)
    return rows


def main() -> None:
    quick = "--quick" in sys.argv
    rows = real_rows(quick) + rendered_rows(quick)
    print(
        "| set | views | OpenCV best half-window | OpenCV mono RMS px | microcal mono RMS px "
        "| OpenCV error to truth px | microcal error to truth px |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, r in rows:
        t_cv = r.get("opencv_truth_px", np.nan)
        t_mc = r.get("microcal_truth_px", np.nan)
        truth = f"{t_cv:.3f} | {t_mc:.3f}" if np.isfinite(t_mc) else "- | -"
        print(
            f"| {label} | {int(r['views'])} | {int(r['opencv_half'])} | "
            f"{r['opencv_rms_px']:.3f} | {r['microcal_rms_px']:.3f} | {truth} |"
        )


if __name__ == "__main__":
    main()
