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
from .formats.calibration_file import Calibration, load_calibration
from .geometry import (
    CameraModel,
    camera_centre,
    decompose_projection_matrix,
    estimate_projection_matrix,
    project_points,
    reprojection_error,
    triangulate,
    triangulate_optimal,
    triangulation_covariance,
)
from .kinematics import (
    KinematicModel,
    fit_matrix_model,
    fit_polynomial_model,
    stepwise_fit,
)
from .metrics.error_summary import ErrorSummary, summarize_errors

__all__ = [
    "Calibration",
    "CameraModel",
    "DegenerateDataError",
    "DetectionError",
    "DeviceError",
    "ErrorSummary",
    "FormatError",
    "InputError",
    "KinematicModel",
    "LimitError",
    "MicrocalError",
    "__version__",
    "camera_centre",
    "decompose_projection_matrix",
    "estimate_projection_matrix",
    "fit_matrix_model",
    "fit_polynomial_model",
    "load_calibration",
    "project_points",
    "reprojection_error",
    "stepwise_fit",
    "summarize_errors",
    "triangulate",
    "triangulate_optimal",
    "triangulation_covariance",
]
