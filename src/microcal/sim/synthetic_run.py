"""A synthetic acquisition run without rendering: true positions seen through the cameras.

For the identification tests and benchmarks, without the cost of rendering and detection:
random joint commands (the thesis's uniform design), the true end-effector positions (with
hysteresis from the order of the moves), their projections into both cameras perturbed by
the virtual point's pixel noise (thesis Table 4-1), and the optimal triangulation of those
pixels with its covariance. Seeded; ground truth included for tests and benchmarks.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import InputError
from ..geometry import AnyCamera, triangulate_optimal, triangulation_covariance
from ..kinematics.designs import make_design
from ..thesis.cameras import thesis_cameras
from ..thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM
from ..thesis.figures import VIRTUAL_POINT_STD_PX
from .kinematics import TrueKinematics, approach_signs
from .platforms import SimPlatform
from .thesis_kinematics import thesis_kinematics

__all__ = [
    "RENDERED_VIRTUAL_POINT_STD_PX",
    "VIRTUAL_POINT_STD_PX",
    "ProjectedProbe",
    "SyntheticRun",
    "measure_positions",
    "synthetic_run",
]


#: Pixel noise (u, v) of the fast path of a study: the independent noise at which projecting
#: and triangulating gives the 3D error of the simulator's rendered pipeline with 5 frames
#: averaged (0.27-0.37 / 0.17-0.21 / 0.69-0.72 µm RMS along x / y / z over 25 random poses
#: of the ``thesis`` and ``population`` presets; this gives 0.22 / 0.30 / 0.67). The rendered
#: virtual points' own scatter is larger (0.02-0.045 px), but it is not independent between
#: the cameras, so it does not reach 3D in full.
RENDERED_VIRTUAL_POINT_STD_PX = (0.014, 0.014)


@dataclass(frozen=True)
class SyntheticRun:
    """Commands, truth and measurements of one synthetic run."""

    d_um: FloatArray  # (N, 3) joint commands, in execution order
    true_um: FloatArray  # (N, 3) true positions in {G}
    measured_um: FloatArray  # (N, 3) triangulated from noisy pixels
    covariance_um2: FloatArray  # (N, 3, 3) of the measured positions
    truth: TrueKinematics


def measure_positions(
    p_true_um: FloatArray,
    cameras: tuple[AnyCamera, AnyCamera],
    rng: np.random.Generator,
    pixel_std_px: tuple[float, float] = VIRTUAL_POINT_STD_PX,
    triangulate_with: tuple[AnyCamera, AnyCamera] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Project true points into both cameras, add pixel noise, triangulate optimally.

    ``triangulate_with``: calibrated models of the same cameras (default: the true ones). The
    noisy pixels are then observed through the true lenses and undistorted and triangulated
    with the calibrated models, so the cameras' calibration error reaches the positions as it
    does in a measurement.

    Returns
    -------
    p_um : (N, 3) float
        Measured positions.
    cov_um2 : (N, 3, 3) float
        Their first-order covariance.
    """
    cov_px2 = np.diag(np.square(pixel_std_px))
    n = p_true_um.shape[0]
    # ideal (undistorted) pixels: what triangulation with P expects once a measurement has
    # undistorted its detections
    q = [cam.project(p_true_um, distort=False) + rng.normal(0.0, pixel_std_px, (n, 2))
         for cam in cameras]  # fmt: skip
    c1 = c2 = cov_px2
    if triangulate_with is not None:
        q = [seen.undistort_px(true.distort_px(qi))
             for true, seen, qi in zip(cameras, triangulate_with, q, strict=True)]  # fmt: skip
        cameras = triangulate_with
        # as a measurement counts it: each calibration's own projection error, every frame alike
        c1, c2 = (cov_px2 + np.eye(2) * cam.projection_sigma_px**2 for cam in cameras)
    P1, P2 = cameras[0].P, cameras[1].P
    p = triangulate_optimal(P1, P2, q[0], q[1], cov_px2, cov_px2)
    return p, triangulation_covariance(P1, P2, p, c1, c2)


def synthetic_run(
    n_poses: int = 170,
    seed: int = 0,
    truth: TrueKinematics | None = None,
    cameras: tuple[AnyCamera, AnyCamera] | None = None,
    d_um: FloatArray | None = None,
) -> SyntheticRun:
    """A run of ``n_poses`` uniform random commands over the thesis's travel (or ``d_um``)."""
    rng = np.random.default_rng(seed)
    truth = truth or thesis_kinematics()
    cameras = cameras or thesis_cameras()
    if d_um is None:
        d_um = make_design("random", n_poses, WORKSPACE_MIN_UM, WORKSPACE_MAX_UM, rng)
    true = truth.position_um(d_um, approach_signs(d_um))
    measured, cov = measure_positions(true, cameras, rng)
    return SyntheticRun(d_um, true, measured, cov, truth)


class ProjectedProbe:
    """A vision probe without rendering: the true end-effector projected into two cameras,
    perturbed by the virtual point's pixel noise and triangulated optimally.

    Parameters
    ----------
    truth : callable () -> (3,) float
        The true position now (``SimPlatform.truth_position_um``).
    cameras : two CameraModel
        The cameras the truth is projected through and triangulated with.
    rng : numpy.random.Generator
    pixel_std_px : (2,) float
        Each camera's pixel noise (default thesis Table 4-1).
    frames : int
        The frames averaged in a measurement of that noise: :meth:`measure_with_covariance`
        scales it by sqrt(frames / frames asked for), as averaging independent frames does.
    triangulate_with : two CameraModel, optional
        Calibrated models of the cameras to measure with (see :func:`measure_positions`).
    """

    def __init__(
        self,
        truth: Callable[[], FloatArray],
        cameras: tuple[AnyCamera, AnyCamera],
        rng: np.random.Generator,
        pixel_std_px: tuple[float, float] = VIRTUAL_POINT_STD_PX,
        frames: int = 5,
        triangulate_with: tuple[AnyCamera, AnyCamera] | None = None,
    ) -> None:
        if frames < 1:
            raise InputError(f"frames: expected 1 or more, got {frames}")
        self.truth = truth
        self.frames = int(frames)
        self.triangulate_with = triangulate_with
        self.cameras = cameras
        self.rng = rng
        self.pixel_std_px = pixel_std_px
        self.last_cov_um2: FloatArray = np.full((3, 3), np.nan)

    @classmethod
    def on_platform(
        cls,
        plat: SimPlatform,
        rng: np.random.Generator,
        calibrated: Mapping[str, AnyCamera] | None = None,
    ) -> ProjectedProbe:
        """The probe of a simulated platform's first two cameras, with the rendered
        pipeline's pixel noise (:data:`RENDERED_VIRTUAL_POINT_STD_PX`, 5 frames), measuring
        with their ``calibrated`` models (by camera name) when given, else the true ones."""
        a, b = list(plat.camera_models)[:2]
        true = (plat.camera_models[a], plat.camera_models[b])
        seen = None if calibrated is None else (calibrated[a], calibrated[b])
        return cls(plat.truth_position_um, true, rng, RENDERED_VIRTUAL_POINT_STD_PX,
                   triangulate_with=seen)  # fmt: skip

    def measure(self, d_um: FloatArray) -> FloatArray:
        """Position in {G} (3,) µm (``d_um`` is not needed: nothing is searched for)."""
        p, self.last_cov_um2 = self.measure_with_covariance(d_um, self.frames)
        return p

    def measure_with_covariance(
        self, d_um: FloatArray, frames: int
    ) -> tuple[FloatArray, FloatArray]:
        """Position in {G} (3,) µm and its covariance (3, 3) µm² from ``frames`` frames per
        camera (the closed loop's measurement)."""
        if frames < 1:
            raise InputError(f"frames: expected 1 or more, got {frames}")
        scale = np.sqrt(self.frames / frames)
        std = (self.pixel_std_px[0] * scale, self.pixel_std_px[1] * scale)
        p, cov = measure_positions(self.truth()[None, :], self.cameras, self.rng, std,
                                   self.triangulate_with)  # fmt: skip
        return p[0], cov[0]
