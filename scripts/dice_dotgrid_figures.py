"""Figures of the DICe dot-grid slide set: stereo calibration from partial grids.

Calibrates ``../shared/data/dice_dotgrid_stereo`` (14 stereo pairs of a slide that runs past
every edge of the image, numbered from three hollow marker dots) through
``microcal stereo-calibrate``, then reports: mono and stereo RMS, the triangulated dot pitch
along both axes over the field, and OpenCV's figures from the same dots located the OpenCV
way (the grid detector ``findCirclesGrid`` finds nothing on a partial grid, so OpenCV gets
microcal's numbering with the centres of its own blob detector, and its best of
``calibrateCamera`` / ``calibrateCameraRO`` with the same lens terms).

Usage: python scripts/dice_dotgrid_figures.py [DATA_DIR] [--views N]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from microcal.vision.detect import Detection, detect, to_gray
from microcal.vision.targets import parse_target

#: The slide's spec: 13 x 11 dots of 3.5 mm (all that any view shows), hollow dots at (3, 7),
#: 5 dots to its right and 3 above it.
SPEC = "dotgrid:13x11:3500:1400:markers=3,7/8,7/3,4"
#: The lens model (--lens-model NAME): the default, as a user gets it.
LENS = "auto"
SIZE = (2448, 2048)


def opencv_centres(gray: np.ndarray, det: Detection) -> Detection:
    """The same dots located by OpenCV's blob detector (as ``findCirclesGrid`` does)."""
    params = cv2.SimpleBlobDetector_Params()
    params.minArea, params.maxArea = 500, 60000
    params.filterByConvexity = params.filterByInertia = False
    img8 = np.clip(gray, 0, 255).astype(np.uint8)
    pts = np.array([k.pt for k in cv2.SimpleBlobDetector_create(params).detect(img8)])
    if len(pts) == 0:
        return Detection.none("no blobs")
    d = np.linalg.norm(det.q_px[:, None, :] - pts[None, :, :], axis=2)
    nearest = d.argmin(axis=1)
    ok = d[np.arange(len(nearest)), nearest] < 10.0
    return Detection(True, det.ids[ok], pts[nearest[ok]], method="opencv blobs")


def opencv_figures(target, dets: dict[str, list[Detection]]) -> dict[str, float]:
    P = target.points_um().astype(np.float32)
    out, mono = {}, {}
    flags = cv2.CALIB_FIX_K3
    for cam, ds in dets.items():
        obj = [P[d.ids] for d in ds]
        img = [d.q_px.astype(np.float32) for d in ds]
        rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, SIZE, None, None, flags=flags)
        common = sorted(set.intersection(*[set(d.ids.tolist()) for d in ds]))
        obj_c = [P[common] for _ in ds]
        img_c = [d.q_px[np.searchsorted(d.ids, common)].astype(np.float32) for d in ds]
        rms_ro, K2, dist2, _, _, _ = cv2.calibrateCameraRO(
            obj_c, img_c, SIZE, len(common) - 1, None, None, flags=flags
        )
        out[f"{cam} mono"] = rms
        out[f"{cam} mono (RO)"] = rms_ro
        mono[cam] = (K, dist) if rms <= rms_ro else (K2, dist2)
    obj, left, right = [], [], []
    for a, b in zip(dets["left"], dets["right"], strict=True):
        common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
        obj.append(P[common])
        left.append(a.q_px[ia].astype(np.float32))
        right.append(b.q_px[ib].astype(np.float32))
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-9)
    best = np.inf
    for fl in (cv2.CALIB_FIX_INTRINSIC, cv2.CALIB_USE_INTRINSIC_GUESS | flags):
        r = cv2.stereoCalibrate(obj, left, right, *mono["left"], *mono["right"], SIZE,
                                flags=fl, criteria=crit)[0]  # fmt: skip
        best = min(best, r)
    out["stereo"] = best
    return out


def pitch_figures(cal, target, dets: dict[str, list[Detection]]) -> dict[str, tuple[float, float]]:
    """Triangulated neighbour distances along the grid's x and y: (mean, worst) error, %."""
    from microcal.geometry import triangulate

    left, right = cal.cameras["left"].model, cal.cameras["right"].model
    cols = target.cols
    steps: dict[str, list[tuple[float, int]]] = {"x": [], "y": []}
    for a, b in zip(dets["left"], dets["right"], strict=True):
        common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
        p = triangulate(left.P, right.P, left.undistort_px(a.q_px[ia]),
                        right.undistort_px(b.q_px[ib]))  # fmt: skip
        q = a.q_px[ia]
        where = {int(i): k for k, i in enumerate(common)}
        for i, k in where.items():
            for axis, nxt in (("x", i + 1), ("y", i + cols)):
                if nxt in where and (axis == "y" or (i % cols) + 1 < cols):
                    mid = 0.5 * (q[k] + q[where[nxt]])  # which ninth of the left image
                    cell = int(min(2, mid[0] * 3 // SIZE[0]) * 3 + min(2, mid[1] * 3 // SIZE[1]))
                    steps[axis].append((float(np.linalg.norm(p[where[nxt]] - p[k])), cell))
    out = {}
    for axis, d in steps.items():
        e = (np.array([v for v, _ in d]) / target.pitch_um - 1.0) * 100.0
        cells = np.array([c for _, c in d])
        regional = [float(np.mean(e[cells == c])) for c in range(9) if np.any(cells == c)]
        out[axis] = (float(np.mean(e)), float(np.max(np.abs(e))), len(d), float(np.std(e)),
                     max(regional, key=abs))  # fmt: skip
    return out


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    data = Path(args[0] if args else "../shared/data/dice_dotgrid_stereo")
    n_views = 14
    if "--views" in sys.argv:
        n_views = int(sys.argv[sys.argv.index("--views") + 1])
    global LENS
    if "--lens-model" in sys.argv:
        LENS = sys.argv[sys.argv.index("--lens-model") + 1]
    from microcal.workflows.stereo import stereo_calibrate_images

    with tempfile.TemporaryDirectory() as tmp:
        links = Path(tmp)
        for i in range(1, n_views + 1):
            for s in (0, 1):
                name = f"CalB-sys2-{i:04d}_{s}.jpeg"
                (links / name).symlink_to((data / name).resolve())
        out = links / "cameras.json"
        cal = stereo_calibrate_images(
            SPEC,
            [f"left={links}/CalB-sys2-*_0.jpeg", f"right={links}/CalB-sys2-*_1.jpeg"],
            out,
            lens_model=LENS,
        )
    target = parse_target(SPEC)
    dets: dict[str, list[Detection]] = {"left": [], "right": []}
    ocv: dict[str, list[Detection]] = {"left": [], "right": []}
    for i in range(1, n_views + 1):
        for s, cam in ((0, "left"), (1, "right")):
            gray = to_gray(cv2.imread(str(data / f"CalB-sys2-{i:04d}_{s}.jpeg"), 0))
            det = detect(gray, target)
            dets[cam].append(det)
            ocv[cam].append(opencv_centres(gray, det))
    print(f"views: {n_views} pairs; spec {SPEC}; lens model {LENS}")
    for name, c in cal.cameras.items():
        print(f"microcal {name} mono RMS {c.rms_px:.3f} px ({c.views_used} views)")
    print(f"microcal stereo RMS {cal.rms_px:.3f} px; baseline {cal.baseline_um / 1000:.2f} mm")
    for note in cal.notes:
        print(f"note: {note}")
    for axis, (mean, worst, n, sd, ninth) in pitch_figures(cal, target, dets).items():
        print(f"triangulated pitch along {axis}: mean {mean:+.3f} %, worst ninth of the "
              f"image {ninth:+.3f} %, sd {sd:.3f} %, worst pair {worst:.3f} % "
              f"({n} neighbour pairs)")  # fmt: skip
    for key, value in opencv_figures(target, ocv).items():
        print(f"OpenCV {key} RMS {value:.3f} px")
    for key, value in opencv_figures(target, dets).items():
        print(f"OpenCV on microcal's centres: {key} RMS {value:.3f} px")


if __name__ == "__main__":
    main()
