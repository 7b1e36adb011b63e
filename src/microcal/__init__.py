"""microcal: vision-based automatic calibration of microrobotic systems.

Calibrate a stereo microscope, measure a micromanipulator's end-effector in 3D, identify its
kinematic model, compensate it, and grade the result by ISO 9283. Lengths are in µm, image
coordinates in pixels; see ``docs/conventions.md``.
"""

from ._version import __version__
from .errors import (
    DegenerateDataError,
    DetectionError,
    DeviceError,
    FormatError,
    InputError,
    LimitError,
    MicrocalError,
)
from .geometry import (
    CameraModel,
    ReprojectionSummary,
    camera_centre,
    decompose_projection_matrix,
    estimate_projection_matrix,
    project_points,
    reprojection_error,
    summarize_errors,
    triangulate,
    triangulate_optimal,
    triangulation_covariance,
)

__all__ = [
    "CameraModel",
    "DegenerateDataError",
    "DetectionError",
    "DeviceError",
    "FormatError",
    "InputError",
    "LimitError",
    "MicrocalError",
    "ReprojectionSummary",
    "__version__",
    "camera_centre",
    "decompose_projection_matrix",
    "estimate_projection_matrix",
    "project_points",
    "reprojection_error",
    "summarize_errors",
    "triangulate",
    "triangulate_optimal",
    "triangulation_covariance",
]
