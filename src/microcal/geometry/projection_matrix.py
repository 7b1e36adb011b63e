"""The 3x4 projection matrix: estimation from correspondences, projection, decomposition.

Thesis Eq 3.7-3.16. The estimate is the normalised direct linear transformation (DLT):
both point sets are first moved to their centroid and scaled (Hartley), which makes the
linear system well conditioned; the thesis's plain least squares on raw millimetre and
pixel values is not.

Two forms of P meet here. A camera with a projection centre (pinhole) has ``P[2, :3] != 0``;
its P is normalised so that ``||P[2, :3]|| = 1`` with ``det P[:, :3] > 0``
(:func:`normalize_projection_matrix`). An affine camera (parallel projection, the centre at
infinity) has ``P[2, :3] = 0``; its P is scaled so that ``P[2] = (0, 0, 0, 1)``.
:func:`normalize_camera_matrix` takes either; estimation and decomposition are for pinhole
cameras only.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows
from ..errors import DegenerateDataError

__all__ = [
    "MIN_POINTS",
    "camera_centre",
    "decompose_projection_matrix",
    "estimate_projection_matrix",
    "is_affine_projection_matrix",
    "normalize_camera_matrix",
    "normalize_projection_matrix",
    "project_points",
]

#: Correspondences needed: 11 unknowns, 2 equations per point, and 6 leave one to spare.
MIN_POINTS = 6
#: Relative size of the smallest spread of the 3D points below which they count as coplanar.
COPLANAR_RTOL = 1e-6
#: Relative gap of the DLT system's singular values below which the solution is not unique.
RANK_RTOL = 1e-10


def _similarity(points: FloatArray) -> FloatArray:
    """Hartley normalisation: centroid to origin, mean distance sqrt(dim).

    Returns the (dim+1, dim+1) homogeneous transform.
    """
    dim = points.shape[1]
    centroid = points.mean(axis=0)
    mean_dist = float(np.linalg.norm(points - centroid, axis=1).mean())
    scale = np.sqrt(dim) / mean_dist
    T = np.eye(dim + 1)
    T[:dim, :dim] *= scale
    T[:dim, dim] = -scale * centroid
    return T


def is_affine_projection_matrix(P: ArrayLike) -> bool:
    """True if P is an affine camera's (``P[2, :3] = 0``: parallel projection).

    Parameters
    ----------
    P : (3, 4) float

    Returns
    -------
    bool
        ``||P[2, :3]|| == 0``, the test :func:`normalize_projection_matrix` rejects.
    """
    P = as_array(P, "P", (3, 4))
    return float(np.linalg.norm(P[2, :3])) == 0


def normalize_projection_matrix(P: ArrayLike) -> FloatArray:
    """Fix the scale and sign of a pinhole camera's projection matrix.

    Parameters
    ----------
    P : (3, 4) float
        ``P[2, :3] != 0`` (a camera with a projection centre).

    Returns
    -------
    P : (3, 4) float
        Scaled so that ``||P[2, :3]|| = 1`` and ``det P[:, :3] > 0``; then ``P[2] @ [p; 1]`` is
        the depth of ``p`` in front of the camera, in the world's unit.

    Raises
    ------
    DegenerateDataError
        If ``P[2, :3] = 0`` (an affine camera: use :func:`normalize_camera_matrix`).
    """
    P = as_array(P, "P", (3, 4))
    norm = float(np.linalg.norm(P[2, :3]))
    if norm == 0:
        raise DegenerateDataError(
            "P: expected a finite camera (P[2, :3] != 0), got P[2, :3] = 0 (an affine camera)"
        )
    sign = 1.0 if np.linalg.det(P[:, :3]) >= 0 else -1.0
    out: FloatArray = P * (sign / norm)
    return out


def normalize_camera_matrix(P: ArrayLike) -> FloatArray:
    """Fix the scale and sign of a pinhole or an affine camera's projection matrix.

    Parameters
    ----------
    P : (3, 4) float
        Any scale and sign.

    Returns
    -------
    P : (3, 4) float
        Pinhole (``P[2, :3] != 0``): :func:`normalize_projection_matrix`, unchanged.
        Affine (``P[2, :3] = 0``): ``P / P[2, 3]``, so that ``P[2] = (0, 0, 0, 1)``; the first
        two rows map ``[p; 1]`` straight to pixels.

    Raises
    ------
    DegenerateDataError
        If ``P[2] = 0`` (no camera).
    """
    P = as_array(P, "P", (3, 4))
    if not is_affine_projection_matrix(P):
        return normalize_projection_matrix(P)
    if P[2, 3] == 0:
        raise DegenerateDataError(
            "P: expected a pinhole (P[2, :3] != 0) or an affine camera (P[2] = (0, 0, 0, w), "
            "w != 0), got P[2] = 0"
        )
    out: FloatArray = P / P[2, 3]
    return out


def estimate_projection_matrix(p_um: ArrayLike, q_px: ArrayLike) -> FloatArray:
    """Estimate P from 3D-2D correspondences by the normalised DLT (thesis Eq 3.7-3.15).

    Parameters
    ----------
    p_um : (N, 3) float
        Points in the world frame, µm; N >= 6, not all on one plane.
    q_px : (N, 2) float
        Their images, pixels (undistorted, or distortion is absorbed in the error).

    Returns
    -------
    P : (3, 4) float
        Normalised as :func:`normalize_projection_matrix` says.

    Raises
    ------
    DegenerateDataError
        Fewer than 6 points, coplanar points, or a configuration that leaves P undetermined.
    InputError
        Wrong shapes or non-finite values.
    """
    p = as_array(p_um, "p_um", (None, 3))
    q = as_array(q_px, "q_px", (None, 2))
    n = p.shape[0]
    if q.shape[0] != n:
        raise DegenerateDataError(
            f"p_um and q_px: expected the same number of points, got {n} and {q.shape[0]}"
        )
    if n < MIN_POINTS:
        raise DegenerateDataError(
            f"estimate_projection_matrix: expected at least {MIN_POINTS} correspondences, got {n}"
        )
    spread = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    if spread[0] == 0 or spread[2] <= COPLANAR_RTOL * spread[0]:
        raise DegenerateDataError(
            "estimate_projection_matrix: the 3D points lie on one plane (or line); "
            "a projection matrix needs non-coplanar points: add views at other depths"
        )
    if np.ptp(q, axis=0).min() == 0:
        raise DegenerateDataError(
            "estimate_projection_matrix: the image points do not span two dimensions"
        )
    T3 = _similarity(p)
    T2 = _similarity(q)
    pn = p @ T3[:3, :3].T + T3[:3, 3]
    qn = q @ T2[:2, :2].T + T2[:2, 2]
    ph = np.hstack([pn, np.ones((n, 1))])
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = ph
    A[0::2, 8:12] = -qn[:, 0:1] * ph
    A[1::2, 4:8] = ph
    A[1::2, 8:12] = -qn[:, 1:2] * ph
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    if s[-2] <= RANK_RTOL * s[0]:
        raise DegenerateDataError(
            "estimate_projection_matrix: the correspondences do not determine P uniquely "
            "(points on a critical configuration); spread the points over the volume"
        )
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.solve(T2, Pn @ T3)
    return normalize_projection_matrix(P)


def project_points(P: ArrayLike, p_um: ArrayLike) -> FloatArray:
    """Project world points with a projection matrix (thesis Eq 3.6).

    Parameters
    ----------
    P : (3, 4) float
    p_um : (N, 3) or (3,) float
        World points, µm.

    Returns
    -------
    q_px : (N, 2) float
    """
    P = as_array(P, "P", (3, 4))
    p = as_rows(p_um, "p_um", 3)
    h = p @ P[:, :3].T + P[:, 3]
    out: FloatArray = h[:, :2] / h[:, 2:3]
    return out


def decompose_projection_matrix(P: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Split P into intrinsics and pose by RQ decomposition (thesis Eq 3.16).

    Parameters
    ----------
    P : (3, 4) float
        Any scale and sign.

    Returns
    -------
    K : (3, 3) float
        Upper triangular, positive diagonal, ``K[2, 2] = 1``.
    R : (3, 3) float
        Rotation, det +1.
    t : (3,) float
        Translation in the world's unit, ``P ~ K [R | t]``.

    Raises
    ------
    DegenerateDataError
        If ``P[:, :3]`` is singular (a camera at infinity).
    """
    P = normalize_projection_matrix(P)
    M = P[:, :3]
    if abs(np.linalg.det(M)) <= 1e-12 * float(np.abs(M).max()) ** 3:
        raise DegenerateDataError(
            "decompose_projection_matrix: P[:, :3] is singular; the camera centre is at infinity"
        )
    K, R = scipy.linalg.rq(M)
    D = np.diag(np.sign(np.diag(K)))
    K = K @ D
    R = D @ R
    t = np.asarray(scipy.linalg.solve_triangular(K, P[:, 3]), dtype=np.float64)
    K = np.asarray(K / K[2, 2], dtype=np.float64)
    return K, np.asarray(R, dtype=np.float64), t


def camera_centre(P: ArrayLike) -> FloatArray:
    """The projection centre C of P (``P [C; 1] = 0``).

    Parameters
    ----------
    P : (3, 4) float

    Returns
    -------
    C : (3,) float
        In the world frame, the world's unit.

    Raises
    ------
    DegenerateDataError
        For an affine camera (``P[2, :3] = 0``): its centre is at infinity.
    """
    P = as_array(P, "P", (3, 4))
    if is_affine_projection_matrix(P):
        raise DegenerateDataError(
            "camera_centre: expected a pinhole camera (P[2, :3] != 0), got an affine one "
            "(P[2, :3] = 0); its centre is at infinity"
        )
    return np.asarray(-np.linalg.solve(P[:, :3], P[:, 3]), dtype=np.float64)
