"""The camera-geometry check that ``microcal demo`` runs while the full pipeline is built.

On the thesis's two cameras (section 5.1) it does what the stereo calibration and the 3D
measurement will do, on synthetic pixel coordinates instead of rendered images:

1. a dot grid (pitch 125 µm, the thesis's target) seen at known heights, its dot centres
   perturbed by pixel noise, gives each camera's P by normalised DLT (Eq 3.7-3.15);
2. P is decomposed into K, R, t (Eq 3.16);
3. end-effector points at random manipulator positions, perturbed by the virtual point's
   pixel noise (thesis Table 4-1), are triangulated (Eq 3.18, optimal) with their covariance;
4. the errors against the known truth are reported: reprojection RMS in px, 3D error in µm,
   and whether the predicted uncertainty is honest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._validation import FloatArray
from ..geometry import (
    decompose_projection_matrix,
    estimate_projection_matrix,
    reprojection_error,
    triangulate,
    triangulation_covariance,
)
from ..synthetic import dot_grid_points, random_points, thesis_cameras
from ..thesis_figures import REPROJECTION_ERROR_SIDE_PX, REPROJECTION_ERROR_TOP_PX

#: Thesis Table 4-1: standard deviation of the virtual point, px (x, y).
VIRTUAL_POINT_STD_PX = (0.087, 0.045)
#: Pixel noise of one dot centre on the calibration target (a dot averages many edge pixels).
DOT_CENTRE_STD_PX = 0.07


@dataclass(frozen=True)
class CameraCheck:
    """Calibration figures of one camera."""

    name: str
    rms_px: float
    thesis_rms_px: float
    fx_px: float
    fy_px: float
    centre_error_um: float


@dataclass(frozen=True)
class GeometryCheck:
    """What the geometry check measured."""

    cameras: tuple[CameraCheck, CameraCheck]
    n_calibration_points: int
    n_points: int
    rms_error_um: float
    max_error_um: float
    mean_predicted_std_um: FloatArray  # (3,) x, y, z
    mahalanobis_mean_square: float  # 3 for an honest covariance


def run_geometry_check(seed: int = 0, n_points: int = 170) -> GeometryCheck:
    """Calibrate the thesis's cameras from synthetic dot-grid data and measure points.

    Parameters
    ----------
    seed : int
        Seed of the pixel noise and the random positions.
    n_points : int
        End-effector positions to triangulate (the thesis used 170).
    """
    rng = np.random.default_rng(seed)
    cams = thesis_cameras()
    grid = np.vstack([dot_grid_points(60, 60, 125.0, z) for z in (0.0, 1200.0, 2400.0, 3600.0)])
    checks = []
    Ps = []
    for cam, thesis_rms in zip(
        cams, (REPROJECTION_ERROR_TOP_PX, REPROJECTION_ERROR_SIDE_PX), strict=True
    ):
        q = cam.project(grid) + rng.normal(0.0, DOT_CENTRE_STD_PX, (grid.shape[0], 2))
        P = estimate_projection_matrix(grid, q)
        K, R, t = decompose_projection_matrix(P)
        err = reprojection_error(P, grid, q)
        checks.append(
            CameraCheck(
                name=cam.name,
                rms_px=float(np.sqrt(np.mean(err**2))),
                thesis_rms_px=thesis_rms,
                fx_px=float(K[0, 0]),
                fy_px=float(K[1, 1]),
                centre_error_um=float(np.linalg.norm(-R.T @ t - cam.centre_um)),
            )
        )
        Ps.append(P)
    p = random_points(rng, n_points)
    cov_q = np.diag(np.square(VIRTUAL_POINT_STD_PX))
    q1 = cams[0].project(p) + rng.multivariate_normal([0, 0], cov_q, n_points)
    q2 = cams[1].project(p) + rng.multivariate_normal([0, 0], cov_q, n_points)
    est = triangulate(Ps[0], Ps[1], q1, q2, method="optimal")
    cov = triangulation_covariance(Ps[0], Ps[1], est, cov_q, cov_q)
    d = est - p
    m2 = np.einsum("ni,nij,nj->n", d, np.linalg.inv(cov), d)
    norms = np.linalg.norm(d, axis=1)
    return GeometryCheck(
        cameras=(checks[0], checks[1]),
        n_calibration_points=int(grid.shape[0]),
        n_points=n_points,
        rms_error_um=float(np.sqrt(np.mean(norms**2))),
        max_error_um=float(norms.max()),
        mean_predicted_std_um=np.sqrt(np.diagonal(cov, axis1=1, axis2=2)).mean(axis=0),
        mahalanobis_mean_square=float(m2.mean()),
    )


@dataclass(frozen=True)
class IdentificationCheck:
    """Validation figures (µm, Eq 5.1 over the validation poses) of both models and the oracle."""

    n_poses: int
    n_fit: int
    matrix: dict[str, float]
    polynomial: dict[str, float]
    oracle: dict[str, float]
    polynomial_terms: dict[str, list[str]]


#: Thesis section 5.2.2: prediction errors over the 60 validation poses, µm.
THESIS_VALIDATION_UM = {
    "matrix": {"mean": 4.58, "std": 2.50, "max": 8.35},
    "polynomial": {"mean": 2.59, "std": 1.32, "max": 5.28},
}


def _number(value: object) -> float:
    assert isinstance(value, int | float)
    return float(value)


def run_identification_check(seed: int = 0, n_poses: int = 170) -> IdentificationCheck:
    """Identify both models on a synthetic run of the thesis preset, validate the thesis's way.

    The run's true positions come from the simulator's true kinematics; the measured ones
    are their projections into the thesis's cameras with the virtual point's pixel noise,
    triangulated. The oracle predicts with the true kinematics.
    """
    from ..error_summary import summarize_errors
    from ..sim.synthetic_run import synthetic_run
    from .identification import default_train, identify

    run = synthetic_run(n_poses, seed=seed)
    n_fit = default_train(n_poses)
    figures = {}
    terms: dict[str, list[str]] = {}
    kinds: tuple[Literal["matrix"], Literal["polynomial"]] = ("matrix", "polynomial")
    for kind in kinds:
        ident = identify(run.d_um, run.measured_um, kind, train=n_fit)
        figures[kind] = {k: _number(ident.validation[f"{k}_um"]) for k in ("mean", "std", "max")}
        if kind == "polynomial":
            terms = {
                axis: [name for name, _, _ in ident.model.axis_terms(i)]
                for i, axis in enumerate("xyz")
            }
    oracle = summarize_errors(np.linalg.norm(run.measured_um[n_fit:] - run.true_um[n_fit:], axis=1))
    return IdentificationCheck(
        n_poses,
        n_fit,
        figures["matrix"],
        figures["polynomial"],
        {"mean": oracle.mean, "std": oracle.std, "max": oracle.max},
        terms,
    )
