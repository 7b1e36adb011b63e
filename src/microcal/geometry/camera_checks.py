"""Is a set of cameras usable at all? Checks that a calibration file's numbers make cameras.

A calibration can be numerically valid and physically absurd: a distortion polynomial that
folds back inside the image (two image points for one direction: corners are then matched
to the wrong ray), or two "cameras" that are one view twice (triangulation from them has no
depth). These checks find such files before they give positions.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .affine_camera import AffineCamera
from .camera_kinds import AnyCamera
from .camera_model import CameraModel, distort_normalized

__all__ = ["MAX_EDGE_STRETCH", "distortion_problem", "same_view"]

#: Radii (normalised image coordinates, tan of the angle off axis) searched for a fold:
#: up to 84 degrees off the optical axis.
_MAX_RADIUS = 10.0


#: The share of the image at each border left out of the fold test: a polynomial fitted to
#: views that never reached the image's edge may turn over right there (it does not measure
#: there either); a fold further in is no lens.
EDGE_MARGIN = 0.05
#: The most a lens model may stretch or shrink the image edge's distance from the centre
#: (OpenCV's polynomial models of real non-fisheye lenses stay well within a factor 2).
MAX_EDGE_STRETCH = 3.0


def distortion_problem(model: AnyCamera, directions: int = 72, steps: int = 600) -> str | None:
    """What makes a camera's lens distortion absurd, or None when it is a lens.

    Along rays from the principal point the distorted image must move outwards until it
    leaves the image (the distortion's Jacobian keeps a positive determinant: no fold, which
    would give two image points for one direction), it must leave the image within 84
    degrees of the axis, and at the image edge the distortion may stretch or shrink the
    distance from the centre by at most :data:`MAX_EDGE_STRETCH`.

    Parameters
    ----------
    model : CameraModel or AffineCamera
        (an affine camera's distortion coordinates are in half image diagonals)
    directions, steps : int
        Rays searched and radii per ray (log-spaced up to 84 degrees off axis).
    """
    if not model.has_distortion:
        return None
    w, h = model.image_size_px
    theta = np.linspace(0.0, 2 * np.pi, directions, endpoint=False)
    radius = np.geomspace(1e-4, _MAX_RADIUS, steps)
    rays = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    xy = radius[None, :, None] * rays[:, None, :]
    xy_d, jac = distort_normalized(xy.reshape(-1, 2), model.dist)
    scale = model.radius_px * np.eye(2) if isinstance(model, AffineCamera) else model.K[:2, :2]
    px = (xy_d @ scale.T + model.K[:2, 2]).reshape(directions, steps, 2)
    r_d = np.linalg.norm(xy_d, axis=1).reshape(directions, steps)
    det = np.linalg.det(jac).reshape(directions, steps)
    mx, my = EDGE_MARGIN * w, EDGE_MARGIN * h  # a fit's extrapolation to the very edge may bend
    inside = (
        (px[..., 0] >= mx)
        & (px[..., 0] <= w - 1 - mx)
        & (px[..., 1] >= my)
        & (px[..., 1] <= h - 1 - my)
    )
    for k in range(directions):
        left = np.flatnonzero(~inside[k])  # the ray up to where it first leaves the image
        stop = int(left[0]) if left.size else steps
        bad = np.flatnonzero(~(det[k, :stop] > 0))
        if bad.size:
            u, v = px[k, bad[0]]
            return (f"its lens distortion folds back inside the image near ({u:.0f}, {v:.0f}) px "
                    f"(two image points for one direction)")  # fmt: skip
        if stop == steps:
            return "its lens distortion keeps rays 84 degrees off axis inside the image"
        stretch = r_d[k, stop] / radius[stop]
        if not 1 / MAX_EDGE_STRETCH <= stretch <= MAX_EDGE_STRETCH:
            return (f"its lens distortion changes the image edge's distance from the centre "
                    f"{stretch:.3g} times (a lens stays within {MAX_EDGE_STRETCH:g})")  # fmt: skip
    return None


def same_view(cameras: Mapping[str, CameraModel], tol: float = 1e-6) -> tuple[str, str] | None:
    """Two cameras that see from one centre (one view twice: no depth), or None.

    Two cameras whose centres are closer than ``tol`` times their distance from the origin
    (plus 1 µm) cannot triangulate.
    """
    names = list(cameras)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            ca, cb = cameras[a].centre_um, cameras[b].centre_um
            scale = max(float(np.linalg.norm(ca)), float(np.linalg.norm(cb)), 1.0)
            if float(np.linalg.norm(ca - cb)) <= tol * scale + 1.0:
                return a, b
    return None
