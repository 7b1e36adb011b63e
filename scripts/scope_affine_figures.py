"""Figures of the microscope camera's calibration against its X-Y stage, over seeds.

For each seed a random simulated microscope (:func:`microcal.sim.stage_slide.random_truth`:
pixel size, camera rotation, stage skew, distortion, focus-axis tilt) is calibrated by
``microcal scope-calibrate``'s procedure and compared with its truth: the affine map's
scale (per image axis) and rotation, the pixel size, the focus axis's angle, the
distortion's residual over the field, and how the stated standard deviations cover the
errors; and, from a focus sweep of 15 frames, the field curvature (the focal surface's sag
at the image's corner).

Usage (from the checkout)::

    PYTHONPATH=src python scripts/scope_affine_figures.py --objective 40x --seeds 10
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from microcal.procedures.scope_calibration import calibrate_scope, depth_for, scope_plan
from microcal.sim.stage_slide import SIM_OBJECTIVES, ScopeTruth, StageSlideScope, random_truth
from microcal.vision.stage_affine import ScopeCalibration


def _distortion_residual_px(cal: ScopeCalibration, truth: ScopeTruth, size: int) -> float:
    """RMS over a 21 x 21 grid of the field of the fitted distortion's displacement minus the
    true one, px."""
    r = math.hypot(size, size) / 2
    g = np.linspace(-(size - 1) / 2, (size - 1) / 2, 21)
    u = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2) / r
    rho2 = np.sum(u * u, axis=1, keepdims=True)

    def shift(k1: float, k2: float) -> np.ndarray:
        out: np.ndarray = r * u * (k1 * rho2 + k2 * rho2**2)
        return out

    d = shift(*cal.distortion) - shift(truth.k1, truth.k2)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def one_seed(seed: int, objective: str, size: int, stage_sigma_um: float) -> dict[str, float]:
    """The errors of one seed's calibration against its truth."""
    truth = random_truth(seed, objective)
    scope = StageSlideScope(truth, image_size_px=(size, size), seed=seed,
                            stage_sigma_um=stage_sigma_um)  # fmt: skip
    obj = SIM_OBJECTIVES[objective]
    plan = scope_plan(size * obj.um_per_px, depth_for(obj.numerical_aperture))
    t0 = time.perf_counter()
    d = depth_for(obj.numerical_aperture)
    run = calibrate_scope(scope.move_stage, scope.move_focus, scope.grab, scope.target, plan,
                          sweep_um=np.linspace(-3 * d, 3 * d, 15))  # fmt: skip
    cal, curv = run.calibration, run.curvature
    assert curv is not None
    A = truth.affine_um()[:, :2]
    true_scale = np.linalg.norm(A, axis=0)
    scale_err = cal.scale_um / true_scale - 1
    rot_true = math.degrees(math.atan2(A[1, 0], A[0, 0]))
    rot_err = (cal.rotation_deg - rot_true + 180) % 360 - 180
    ps_true = math.sqrt(abs(np.linalg.det(A)))
    return {
        "seed": seed,
        "s": time.perf_counter() - t0,
        "views": cal.views,
        "missed": len(run.missed),
        "rms_px": cal.rms_px,
        "scale_err_pct": float(np.max(np.abs(scale_err)) * 100),
        "scale_z": float(np.max(np.abs(scale_err * true_scale / cal.scale_sd_um))),
        "rot_err_deg": abs(rot_err),
        "rot_z": abs(rot_err) / cal.rotation_sd_deg,
        "ps_err_pct": (cal.pixel_size_um / ps_true - 1) * 100,
        "ps_z": abs(cal.pixel_size_um - ps_true) / cal.pixel_size_sd_um,
        "tilt_true_deg": truth.focus_tilt_deg,
        "tilt_err_deg": abs(cal.focus_angle_deg - truth.focus_tilt_deg),
        "tilt_z": abs(cal.focus_angle_deg - truth.focus_tilt_deg) / cal.focus_angle_sd_deg,
        "dist_corner_true_px": r_corner(truth, size),
        "dist_resid_px": _distortion_residual_px(cal, truth, size),
        "curv_true_um": truth.field_curvature_um,
        "curv_err_um": abs(curv.corner_um - truth.field_curvature_um),
        "curv_z": abs(curv.corner_um - truth.field_curvature_um) / curv.corner_sd_um,
    }


def r_corner(truth: ScopeTruth, size: int) -> float:
    """The true distortion's displacement at the image corner, px."""
    return math.hypot(size, size) / 2 * (truth.k1 + truth.k2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objective", default="40x", choices=sorted(SIM_OBJECTIVES))
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--size", type=int, default=512, help="image width and height, px")
    ap.add_argument("--stage-sigma-um", type=float, default=0.0,
                    help="the stage's error of position per axis, µm")  # fmt: skip
    args = ap.parse_args()
    rows = []
    for seed in range(args.seeds):
        row = one_seed(seed, args.objective, args.size, args.stage_sigma_um)
        rows.append(row)
        print(
            f"seed {seed}: {row['views']} views ({row['missed']} missed), RMS "
            f"{row['rms_px']:.4f} px; scale {row['scale_err_pct']:.5f} % (z {row['scale_z']:.1f}), "
            f"rotation {row['rot_err_deg']:.5f}° (z {row['rot_z']:.1f}), pixel size "
            f"{row['ps_err_pct']:+.5f} %, focus angle {row['tilt_true_deg']:.3f}° err "
            f"{row['tilt_err_deg']:.4f}° (z {row['tilt_z']:.1f}), distortion corner "
            f"{row['dist_corner_true_px']:+.3f} px resid {row['dist_resid_px']:.4f} px, field "
            f"curvature {row['curv_true_um']:+.3f} µm err {row['curv_err_um']:.3f} µm (z "
            f"{row['curv_z']:.1f}) [{row['s']:.1f} s]",
            flush=True,
        )
    print(f"\n{args.objective}, {args.size}x{args.size} px, stage error {args.stage_sigma_um} µm, "
          f"{len(rows)} seeds: worst / median")  # fmt: skip
    for key, label in (("scale_err_pct", "scale error, % (worst axis)"),
                       ("rot_err_deg", "rotation error, deg"),
                       ("ps_err_pct", "pixel size error, %"),
                       ("tilt_err_deg", "focus-axis angle error, deg"),
                       ("dist_resid_px", "distortion residual RMS, px"),
                       ("curv_err_um", "field curvature (corner sag) error, µm"),
                       ("rms_px", "features' RMS, px")):  # fmt: skip
        v = np.abs([r[key] for r in rows])
        print(f"  {label}: {v.max():.5f} / {np.median(v):.5f}")
    for key, label in (("scale_z", "scale"), ("rot_z", "rotation"), ("ps_z", "pixel size"),
                       ("tilt_z", "focus angle"), ("curv_z", "field curvature")):  # fmt: skip
        z = np.array([r[key] for r in rows])
        print(
            f"  {label}: |error| / stated SD: median {np.median(z):.2f}, max {z.max():.2f}, "
            f"within 2 SD {np.mean(z < 2) * 100:.0f} %"
        )


if __name__ == "__main__":
    main()
