"""Camera geometry (pure math layer): camera models, projection matrices, triangulation.

Everything here depends on numpy and scipy only. Lengths are in micrometres, image
coordinates in pixels (OpenCV's convention: (x, y) = (column, row), origin at the centre of
the top-left pixel), points are rows.
"""

from .affine_camera import AffineCamera
from .camera_kinds import CAMERA_KINDS, AnyCamera
from .camera_model import CameraModel
from .camera_protocol import CameraModelProtocol, check_camera_model
from .projection_matrix import (
    camera_centre,
    decompose_projection_matrix,
    estimate_projection_matrix,
    project_points,
)
from .reprojection import reprojection_error
from .triangulation import (
    triangulate,
    triangulate_cameras,
    triangulate_optimal,
    triangulate_views,
    triangulation_covariance,
)

__all__ = [
    "CAMERA_KINDS",
    "AffineCamera",
    "AnyCamera",
    "CameraModel",
    "CameraModelProtocol",
    "camera_centre",
    "check_camera_model",
    "decompose_projection_matrix",
    "estimate_projection_matrix",
    "project_points",
    "reprojection_error",
    "triangulate",
    "triangulate_cameras",
    "triangulate_optimal",
    "triangulate_views",
    "triangulation_covariance",
]
