"""microcal: vision-based automatic calibration of microrobotic systems.

Calibrate a stereo microscope, measure a micromanipulator's end-effector in 3D, identify its
kinematic model, compensate it, and grade the result by ISO 9283. Lengths are in µm, image
coordinates in pixels; see ``docs/conventions.md``.

``import microcal`` loads only the version and the errors; every other public name (and every
subpackage, such as ``microcal.geometry``) is imported on first use (PEP 562), so that a
script pays for scipy, pydantic or OpenCV only when it uses what needs them.
"""

from typing import TYPE_CHECKING

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

if TYPE_CHECKING:  # what the lazy names are, for type checkers; at run time see _LAZY
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
    from .workflows.station import open_station

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
    "open_station",
    "project_points",
    "reprojection_error",
    "stepwise_fit",
    "summarize_errors",
    "triangulate",
    "triangulate_optimal",
    "triangulation_covariance",
]

# public name -> the module (relative to this package) that defines it, imported on first use
_LAZY = {
    "Calibration": "formats.calibration_file",  # pydantic
    "load_calibration": "formats.calibration_file",
    "open_station": "workflows.station",  # the rig's devices, the vision stack
    "CameraModel": "geometry",  # scipy
    "camera_centre": "geometry",
    "decompose_projection_matrix": "geometry",
    "estimate_projection_matrix": "geometry",
    "project_points": "geometry",
    "reprojection_error": "geometry",
    "triangulate": "geometry",
    "triangulate_optimal": "geometry",
    "triangulation_covariance": "geometry",
    "KinematicModel": "kinematics",  # scipy.stats
    "fit_matrix_model": "kinematics",
    "fit_polynomial_model": "kinematics",
    "stepwise_fit": "kinematics",
    "ErrorSummary": "metrics.error_summary",
    "summarize_errors": "metrics.error_summary",
}


def __getattr__(name: str) -> object:
    """Import a lazy public name, or a subpackage, on first use and keep it."""
    from importlib import import_module, util

    if name in _LAZY:
        value: object = getattr(import_module(f"{__name__}.{_LAZY[name]}"), name)
    elif not name.startswith("_") and util.find_spec(f"{__name__}.{name}") is not None:
        value = import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names (loaded or not) and the subpackages imported so far."""
    return sorted({*globals(), *__all__} - {"TYPE_CHECKING", "_LAZY"})
