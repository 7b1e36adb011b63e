"""The thesis's reference experiment: its workspace, test poses and fit / validation split.

Pure data (section numbers are the thesis's). The figures it published are in
:mod:`microcal.thesis.figures`, its cameras in :mod:`microcal.thesis.cameras` and the
simulator's preset kinematics sized after it in :mod:`microcal.sim.thesis_kinematics`.
"""

from __future__ import annotations

import numpy as np

from .._validation import FloatArray

__all__ = [
    "DECOUPLING_PATH_UM",
    "SPLIT",
    "TABLE_5_2_POSES_UM",
    "WORKSPACE_MAX_UM",
    "WORKSPACE_MIN_UM",
]

#: The manipulator's travel in the thesis's experiments (Table 5-2, Fig 5.5): x, y up to
#: 8000 µm and z up to 4800 µm, in {G}.
WORKSPACE_MIN_UM: FloatArray = np.array([0.0, 0.0, 0.0])
WORKSPACE_MAX_UM: FloatArray = np.array([8000.0, 8000.0, 4800.0])
#: Thesis Table 5-2: the desired poses of the pose-accuracy test, µm from home.
TABLE_5_2_POSES_UM: FloatArray = np.array(
    [[2000, 0, 0], [8000, 0, 0], [0, 2000, 0], [0, 8000, 0], [0, 0, 1500], [0, 0, 3000],
     [1000, 1000, 600], [2000, 2000, 300]], dtype=float,
)  # fmt: skip
#: Thesis Fig 5.5: 8000 µm along x, then 8000 along y, then 4800 along z.
DECOUPLING_PATH_UM = (8000.0, 8000.0, 4800.0)
#: Section 5.2: 110 of 170 poses fit, the last 60 validate.
SPLIT = (110, 170)
