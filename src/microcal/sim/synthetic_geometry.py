"""Seeded synthetic geometry for tests, benchmarks and the simulator (library code).

Cameras looking at a point, random camera pairs around a workspace, random points and
dot-grid targets. No rendering here: this is geometry only (the thesis's own cameras are in
:mod:`microcal.thesis.cameras`).
"""

from __future__ import annotations

import numpy as np

from .._validation import FloatArray
from ..geometry.camera_model import CameraModel
from ..thesis.experiment import WORKSPACE_MAX_UM, WORKSPACE_MIN_UM

__all__ = [
    "dot_grid_points",
    "look_at_camera",
    "random_camera_pair",
    "random_points",
]


def look_at_camera(
    centre_um: FloatArray,
    target_um: FloatArray,
    f_px: float,
    image_size_px: tuple[int, int],
    *,
    up: FloatArray | None = None,
    name: str = "camera",
) -> CameraModel:
    """A distortion-free camera at ``centre_um`` whose optical axis passes through ``target_um``.

    Parameters
    ----------
    centre_um, target_um : (3,) float
    f_px : float
        Focal length in pixels (fx = fy); principal point at the image centre.
    image_size_px : (int, int)
    up : (3,) float, optional
        A direction that appears upwards (towards -y) in the image; +y of the world by default.
    """
    z = np.asarray(target_um, float) - np.asarray(centre_um, float)
    z /= np.linalg.norm(z)
    up_v = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, float)
    x = np.cross(-up_v, z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    t = -R @ np.asarray(centre_um, float)
    w, h = image_size_px
    K = np.array([[f_px, 0.0, (w - 1) / 2], [0.0, f_px, (h - 1) / 2], [0.0, 0.0, 1.0]])
    return CameraModel(K, np.zeros(5), R, t, image_size_px, name)


def random_camera_pair(
    rng: np.random.Generator,
    target_um: FloatArray,
    *,
    distance_um: float = 300_000.0,
    f_px: float = 14_000.0,
    min_angle_deg: float = 20.0,
    max_angle_deg: float = 90.0,
    image_size_px: tuple[int, int] = (1600, 1200),
) -> tuple[CameraModel, CameraModel]:
    """Two cameras looking at ``target_um`` from random directions with a stereo angle in range.

    Parameters
    ----------
    rng : numpy.random.Generator
    target_um : (3,) float
        The point both optical axes pass through.
    """
    target = np.asarray(target_um, float)
    d1 = rng.normal(size=3)
    d1 /= np.linalg.norm(d1)
    angle = np.deg2rad(rng.uniform(min_angle_deg, max_angle_deg))
    ortho = np.cross(d1, rng.normal(size=3))
    ortho /= np.linalg.norm(ortho)
    d2 = np.cos(angle) * d1 + np.sin(angle) * ortho
    cams = []
    for i, d in enumerate((d1, d2)):
        dist = distance_um * rng.uniform(0.8, 1.2)
        cams.append(
            look_at_camera(
                target - dist * d,
                target,
                f_px * rng.uniform(0.8, 1.2),
                image_size_px,
                up=rng.normal(size=3),
                name=f"cam{i + 1}",
            )
        )
    return cams[0], cams[1]


def random_points(
    rng: np.random.Generator,
    n: int,
    low_um: FloatArray = WORKSPACE_MIN_UM,
    high_um: FloatArray = WORKSPACE_MAX_UM,
) -> FloatArray:
    """``n`` points uniformly distributed in the box [low, high], µm; (n, 3)."""
    out: FloatArray = rng.uniform(low_um, high_um, size=(n, 3))
    return out


def dot_grid_points(cols: int, rows: int, pitch_um: float, z_um: float = 0.0) -> FloatArray:
    """Centres of a dot grid in its own plane z = ``z_um``, first dot at the origin.

    Returns
    -------
    p_um : (cols * rows, 3) float
        Row by row: x varies fastest.
    """
    gx, gy = np.meshgrid(np.arange(cols) * pitch_um, np.arange(rows) * pitch_um)
    return np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, float(z_um))])
