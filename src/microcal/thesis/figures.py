"""Figures published in the thesis that microcal reproduces and compares against.

Source: "Vision based automatic calibration of microrobotic system", master's thesis,
Tampere University of Technology, 2012. Section numbers are the thesis's. Pure data.
"""

from __future__ import annotations

import numpy as np

from .._validation import FloatArray

__all__ = [
    "CLAIMED_ACCURACY_UM",
    "DECOUPLING_UM",
    "ONE_CORNER_STD_PX",
    "POSE_ACCURACY_UM",
    "P_SIDE_MM",
    "P_TOP_MM",
    "REPROJECTION_ERROR_SIDE_PX",
    "REPROJECTION_ERROR_TOP_PX",
    "SIDE_IMAGE_SIZE_PX",
    "TOP_IMAGE_SIZE_PX",
    "VALIDATION_UM",
    "VIRTUAL_POINT_STD_PX",
    "projection_matrix_um",
]

#: Section 5.1: camera matrix P of the top camera, world in millimetres (three significant digits).
P_TOP_MM: FloatArray = np.array(
    [
        [1.49e04, -5.47e02, 7.09e02, 1.61e05],
        [4.30e01, 1.17e04, 8.83e03, 7.93e04],
        [-6.28e-03, -5.67e-01, 8.23e-01, 3.24e02],
    ]
)
#: Section 5.1: camera matrix P' of the side camera, world in millimetres.
P_SIDE_MM: FloatArray = np.array(
    [
        [1.28e04, 1.45e02, -4.54e02, 8.41e04],
        [-9.99e01, 1.28e04, 5.45e02, 4.13e04],
        [8.51e-02, -1.52e-04, 9.96e-01, 2.84e02],
    ]
)
#: Section 5.1, by Eq 3.19.
REPROJECTION_ERROR_TOP_PX = 0.090917014
REPROJECTION_ERROR_SIDE_PX = 0.054174204
#: Section 2.4: top camera 1600 x 1200 px; side camera 2452 x 2056 px, binned 2 x 2 in use.
TOP_IMAGE_SIZE_PX = (1600, 1200)
SIDE_IMAGE_SIZE_PX = (1226, 1028)


def projection_matrix_um(P_mm: FloatArray) -> FloatArray:
    """Convert a projection matrix for world points in mm into one for points in µm.

    Parameters
    ----------
    P_mm : (3, 4) float

    Returns
    -------
    P_um : (3, 4) float
        ``P_um [p_um; 1] = P_mm [p_mm; 1] / 1000``: the same image points.
    """
    out: FloatArray = np.hstack([P_mm[:, :3], P_mm[:, 3:] * 1e3]) / 1e3
    return out


#: Section 5.2.2: prediction errors over the 60 validation poses, µm.
VALIDATION_UM = {
    "matrix": {"mean": 4.58, "std": 2.50, "max": 8.35},
    "polynomial": {"mean": 2.59, "std": 1.32, "max": 5.28},
}
#: Table 4-1: standard deviation of one corner and of the virtual point, px (x, y).
ONE_CORNER_STD_PX = (0.207, 0.172)
VIRTUAL_POINT_STD_PX = (0.087, 0.045)
#: Tables 5-2, 5-3, 5-4: mean and worst pose accuracy AP_P, µm.
POSE_ACCURACY_UM = {"uncalibrated": (7.83, 23.52), "matrix": (4.65, 10.0), "optimal": (4.41, 9.14)}
#: Table 5-5: undesired displacement [min, max] per axis during the decoupling test, µm.
DECOUPLING_UM = {
    "uncalibrated": {"x": (-6.14, -0.104), "y": (-25.13, 3.21), "z": (-4.68, 10.55)},
    "matrix": {"x": (-5.29, 0.04), "y": (-5.53, 5.63), "z": (-0.88, 6.07)},
    "optimal": {"x": (-4.33, 0.21), "y": (-5.11, 3.64), "z": (-0.71, 5.99)},
}
#: Table 5-6: integration index Ω per axis, µm x sampling unit (the thesis's sampling).
OMEGA_UM = {
    "uncalibrated": {"x": 120.83, "y": 342.61, "z": 97.84},
    "matrix": {"x": 92.78, "y": 45.75, "z": 100.54},
    "optimal": {"x": 90.54, "y": 48.92, "z": 98.04},
}
#: Section 3.3: the claimed (not measured) accuracy of the stereo measurement, µm.
CLAIMED_ACCURACY_UM = 3.0
