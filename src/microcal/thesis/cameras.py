"""The thesis's top and side cameras (section 5.1), built from its published matrices."""

from __future__ import annotations

from .._validation import FloatArray
from ..geometry.camera_model import CameraModel
from .figures import (
    P_SIDE_MM,
    P_TOP_MM,
    SIDE_IMAGE_SIZE_PX,
    TOP_IMAGE_SIZE_PX,
    projection_matrix_um,
)

__all__ = ["thesis_cameras"]


def thesis_cameras(
    dist_top: FloatArray | None = None, dist_side: FloatArray | None = None
) -> tuple[CameraModel, CameraModel]:
    """The thesis's top and side cameras (section 5.1), world in µm.

    Parameters
    ----------
    dist_top, dist_side : (5,) float, optional
        Lens distortion to add (the thesis's P carry none).

    Returns
    -------
    top, side : CameraModel
    """
    top = CameraModel.from_projection_matrix(
        projection_matrix_um(P_TOP_MM), TOP_IMAGE_SIZE_PX, dist_top, name="top"
    )
    side = CameraModel.from_projection_matrix(
        projection_matrix_um(P_SIDE_MM), SIDE_IMAGE_SIZE_PX, dist_side, name="side"
    )
    return top, side
