"""Chessboard detection with sub-pixel corners, time per image and corner accuracy.

microcal: :func:`microcal.vision.detect.detect` (OpenCV's classic finder, then per-corner
windows from the local spacing and a point-symmetry fit, ``vision/corner_refinement.py``).
Baseline in the same run: OpenCV's classic detector as its tutorial uses it,
``findChessboardCorners`` with default flags, then ``cornerSubPix`` with ``winSize=(11, 11)``
(OpenCV's half-size: a 23 x 23 search window) and EPS + COUNT 30 / 0.001.

Images: rendered wide-angle views of a 9 x 6 board (``sim.calibration_views``: 640 x 480,
blur 0.7 px, noise 2 grey levels), rendered once before timing, with the corners' true
positions; and, when ``../shared/data/boofcv_bumblebee2_chess`` is beside the repository, its
22 real photographs of a 6 x 4 board (no truth: the reprojection RMS of a per-camera
``cv2.calibrateCamera`` on each method's corners stands in for accuracy there).

On the rendered views the squares are some 9-36 px, so the baseline's 23 px window often
reaches a neighbouring corner: its RMS is dominated by such corners, hence also the median and
the share of corners off by more than 0.5 px.

Times are ms per image, so the ratio is microcal's time over the baseline's (> 1: slower).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from microcal.sim.calibration_views import render_calibration_views, wide_angle_camera
from microcal.vision.detect import detect
from microcal.vision.targets import Target, parse_target

from .harness import Case, best_time_s

N_VIEWS = 20
SEED = 0
REPEAT = 3
RENDERED_TARGET = "chessboard:9x6:20000"
PHOTO_TARGET = "chessboard:6x4:30000"
PHOTO_DIR = (
    Path(__file__).resolve().parents[1].parent / "shared" / "data" / "boofcv_bumblebee2_chess"
)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.001)


def opencv_classic(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """OpenCV's tutorial detector: corners (N, 2) or None."""
    found, corners = cv2.findChessboardCorners(image, pattern)
    if not found:
        return None
    corners = cv2.cornerSubPix(image, corners, (11, 11), (-1, -1), SUBPIX_CRITERIA)
    return np.asarray(corners, dtype=np.float64).reshape(-1, 2)


def microcal_corners(image: np.ndarray, target: Target) -> np.ndarray | None:
    det = detect(image, target)
    return det.q_px if det.found else None


def matched_errors(found: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, bool]:
    """Distance of each found corner to the nearest true corner (numbering-independent),
    and whether that matching is one to one (False: some corner landed near a wrong one)."""
    d = np.linalg.norm(found[:, None, :] - truth[None, :, :], axis=2)
    nearest = np.argmin(d, axis=1)
    return d[np.arange(len(found)), nearest], len(np.unique(nearest)) == len(truth)


def _time_per_image_s(fn, images: list[np.ndarray]) -> float:
    return best_time_s(lambda: [fn(im) for im in images], REPEAT) / len(images)


def _rms(errors: list[np.ndarray]) -> float:
    e = np.concatenate(errors) if errors else np.zeros(0)
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def _median(errors: list[np.ndarray]) -> float:
    return float(np.median(np.concatenate(errors))) if errors else float("nan")


def _share_off(errors: list[np.ndarray], limit_px: float = 0.5) -> float:
    return float(np.mean(np.concatenate(errors) > limit_px)) if errors else float("nan")


def rendered_case() -> Case:
    target = parse_target(RENDERED_TARGET)
    views = render_calibration_views(wide_angle_camera(), target, N_VIEWS, seed=SEED)
    images, truth = views.images, views.corners_px
    pattern = target.pattern_size

    ours = [microcal_corners(im, target) for im in images]
    base = [opencv_classic(im, pattern) for im in images]
    both = [i for i in range(N_VIEWS) if ours[i] is not None and base[i] is not None]
    match_ours = {i: matched_errors(q, truth[i]) for i, q in enumerate(ours) if q is not None}
    match_base = {i: matched_errors(q, truth[i]) for i, q in enumerate(base) if q is not None}
    err_ours = [e for e, _ in match_ours.values()]
    err_base = [e for e, _ in match_base.values()]

    t_ours = _time_per_image_s(lambda im: microcal_corners(im, target), images)
    t_base = _time_per_image_s(lambda im: opencv_classic(im, pattern), images)
    return Case(
        name=f"detect {pattern[0]}x{pattern[1]} chessboard, {N_VIEWS} rendered wide-angle views",
        unit="ms/image",
        value=t_ours * 1e3,
        baseline_name="findChessboardCorners + cornerSubPix 11x11",
        baseline=t_base * 1e3,
        details={
            "n_images": N_VIEWS,
            "seed": SEED,
            "blur_px": views.blur_px,
            "noise": views.noise,
            "found": sum(q is not None for q in ours),
            "baseline_found": sum(q is not None for q in base),
            "corner_rms_px": _rms(err_ours),
            "baseline_corner_rms_px": _rms(err_base),
            "corner_median_px": _median(err_ours),
            "baseline_corner_median_px": _median(err_base),
            "share_of_corners_off_by_over_0.5px": _share_off(err_ours),
            "baseline_share_of_corners_off_by_over_0.5px": _share_off(err_base),
            "corner_rms_px_views_both_found": _rms([match_ours[i][0] for i in both]),
            "baseline_corner_rms_px_views_both_found": _rms([match_base[i][0] for i in both]),
            "corner_max_px": float(max(e.max() for e in err_ours)) if err_ours else None,
            "baseline_corner_max_px": float(max(e.max() for e in err_base)) if err_base else None,
            "views_not_one_to_one": sum(not ok for _, ok in match_ours.values()),
            "baseline_views_not_one_to_one": sum(not ok for _, ok in match_base.values()),
        },
    )


def _calibration_rms(corners: list[np.ndarray], target: Target, size: tuple[int, int]) -> float:
    """Reprojection RMS of cv2.calibrateCamera (default flags) on one camera's corners, px."""
    if len(corners) < 3:
        return float("nan")
    obj = target.points_um().astype(np.float32) / 1000.0
    rms, *_ = cv2.calibrateCamera(
        [obj] * len(corners), [c.astype(np.float32) for c in corners], size, None, None
    )
    return float(rms)


def photo_case() -> Case | None:
    files = sorted(PHOTO_DIR.glob("left*.jpg")) + sorted(PHOTO_DIR.glob("right*.jpg"))
    if not files:
        print(f"  skipping the real photographs: {PHOTO_DIR} is absent")
        return None
    target = parse_target(PHOTO_TARGET)
    pattern = target.pattern_size
    images = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]
    ours = [microcal_corners(im, target) for im in images]
    base = [opencv_classic(im, pattern) for im in images]

    details: dict[str, object] = {
        "n_images": len(images),
        "found": sum(q is not None for q in ours),
        "baseline_found": sum(q is not None for q in base),
    }
    h, w = images[0].shape
    for side in ("left", "right"):
        idx = [i for i, f in enumerate(files) if f.name.startswith(side)]
        for key, corners in (("", ours), ("baseline_", base)):
            found = [corners[i] for i in idx if corners[i] is not None]
            details[f"{key}calibration_rms_px_{side}"] = _calibration_rms(found, target, (w, h))

    t_ours = _time_per_image_s(lambda im: microcal_corners(im, target), images)
    t_base = _time_per_image_s(lambda im: opencv_classic(im, pattern), images)
    return Case(
        name=f"detect {pattern[0]}x{pattern[1]} chessboard, {len(images)} Bumblebee2 photographs",
        unit="ms/image",
        value=t_ours * 1e3,
        baseline_name="findChessboardCorners + cornerSubPix 11x11",
        baseline=t_base * 1e3,
        details=details,
    )


#: The settling board: the thesis preset's 4 x 3 board in the top camera's frames.
SETTLE_FRAMES = 12


def followed_case() -> Case:
    """A settling board's frames searched in the region the frame before gave (the settle
    loop before), against followed from the frame before's corners (``previous_px``)."""
    from microcal import sim
    from microcal.vision.roi import box_around

    plat = sim.platform("thesis", seed=SEED)
    plat.manipulator.move_to_um(np.array([3000.0, 2000.0, 1000.0]))
    plat.manipulator.wait_until_stopped(plat.clock)
    target = plat.scene.board
    images = [plat.cameras["top"].grab() for _ in range(SETTLE_FRAMES)]
    first = detect(images[0], target)
    roi = box_around(first.q_px, 30.0)

    def searched(im: np.ndarray) -> np.ndarray:
        return detect(im, target, roi=roi).q_px

    def followed(im: np.ndarray) -> np.ndarray:
        return detect(im, target, roi=roi, previous_px=first.q_px).q_px

    diff = [np.abs(followed(im) - searched(im)).max() for im in images]
    cols, rows = target.pattern_size
    return Case(
        name=f"follow a settling {cols}x{rows} board, {SETTLE_FRAMES} frames",
        unit="ms/frame",
        value=_time_per_image_s(followed, images) * 1e3,
        baseline_name="searched again in the region (the settle loop before)",
        baseline=_time_per_image_s(searched, images) * 1e3,
        details={"max_corner_difference_px": float(max(diff)), "seed": SEED},
    )


def run() -> list[Case]:
    cases = [rendered_case(), followed_case()]
    photo = photo_case()
    if photo is not None:
        cases.append(photo)
    return cases
