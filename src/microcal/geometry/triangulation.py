"""Triangulation of points seen by two cameras, and the uncertainty of the result.

Four functions, all vectorised over N points (no Python loop per point):

- :func:`triangulate`: the linear method of thesis Eq 3.18. Each view gives two equations
  ``(x p3 - p1) . [p; 1] = 0`` and ``(y p3 - p2) . [p; 1] = 0``. With the point finite
  (``[p; 1]``) the four equations are an over-determined 4x3 linear system, solved here by a
  batched QR (modified Gram-Schmidt on the three columns). With each P scaled so that
  ``||p3[:3]|| = 1`` a residual equals the point's depth times its reprojection error, so
  both views are weighted alike. (The thesis solves the same equations for the unit
  homogeneous vector by SVD; both agree exactly without noise and to a small fraction of
  the noise with it.)
- :func:`triangulate_optimal`: the point that minimises the (covariance-weighted)
  reprojection error in both images, by Gauss-Newton started at the linear solution; the
  maximum-likelihood estimate for Gaussian pixel noise.
- :func:`triangulation_covariance`: first-order propagation of the pixel covariance to the
  3x3 covariance of the optimal estimate, ``(J^T W J)^-1``.
- :func:`triangulate_cameras`: the optimal point and its covariance from two camera models
  (anything that implements :class:`~.camera_protocol.CameraModelProtocol`).

A projection matrix may be a pinhole camera's or an affine camera's (``P[2, :3] = 0``,
parallel projection); :func:`~.projection_matrix.normalize_camera_matrix` scales each. An
affine view's linear equations are its reprojection errors in pixels (``P[2] = (0, 0, 0,
1)``), a pinhole view's are depth times them: with one view of each kind the linear point
lies close to the pinhole view's ray, and the optimal method weighs the views by their pixel
noise alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import FloatArray, as_array, as_rows
from ..errors import InputError
from .camera_protocol import CameraModelProtocol, check_camera_model
from .projection_matrix import normalize_camera_matrix

__all__ = [
    "triangulate",
    "triangulate_cameras",
    "triangulate_optimal",
    "triangulate_views",
    "triangulation_covariance",
]


def _lstsq_columns(
    A: FloatArray, b: FloatArray, *, with_rinv: bool = False
) -> tuple[FloatArray, FloatArray | None]:
    """Batched least squares ``min ||A x - b||`` for many small systems at once.

    Parameters
    ----------
    A : (3, m, N) float
        The three columns of each system (column, row, system).
    b : (m, N) float

    Returns
    -------
    x : (3, N) float
    Rinv : (3, 3, N) float or None
        With ``with_rinv``: inverse of the triangular factor R of ``A = Q R``, so that
        ``Rinv Rinv^T = (A^T A)^-1``.
    """
    a0, a1, a2 = A[0], A[1], A[2]
    r00 = np.sqrt(np.einsum("mn,mn->n", a0, a0))
    q0 = a0 / r00
    r01 = np.einsum("mn,mn->n", q0, a1)
    v1 = a1 - r01 * q0
    r11 = np.sqrt(np.einsum("mn,mn->n", v1, v1))
    q1 = v1 / r11
    r02 = np.einsum("mn,mn->n", q0, a2)
    v2 = a2 - r02 * q0
    r12 = np.einsum("mn,mn->n", q1, v2)
    v2 = v2 - r12 * q1
    r22 = np.sqrt(np.einsum("mn,mn->n", v2, v2))
    q2 = v2 / r22
    # Q^T b, orthogonalised in the same order (modified Gram-Schmidt).
    c0 = np.einsum("mn,mn->n", q0, b)
    bb = b - c0 * q0
    c1 = np.einsum("mn,mn->n", q1, bb)
    bb = bb - c1 * q1
    c2 = np.einsum("mn,mn->n", q2, bb)
    # Back substitution R x = c, and R^-1 for the covariance.
    x2 = c2 / r22
    x1 = (c1 - r12 * x2) / r11
    x0 = (c0 - r01 * x1 - r02 * x2) / r00
    if not with_rinv:
        return np.stack([x0, x1, x2]), None
    Rinv = np.zeros((3, 3, r00.shape[0]))
    Rinv[0, 0] = 1.0 / r00
    Rinv[1, 1] = 1.0 / r11
    Rinv[2, 2] = 1.0 / r22
    Rinv[0, 1] = -r01 * Rinv[1, 1] * Rinv[0, 0]
    Rinv[1, 2] = -r12 * Rinv[2, 2] * Rinv[1, 1]
    Rinv[0, 2] = -(r01 * Rinv[1, 2] + r02 * Rinv[2, 2]) * Rinv[0, 0]
    return np.stack([x0, x1, x2]), Rinv


def _check_pair(
    P1: ArrayLike, P2: ArrayLike, q1_px: ArrayLike, q2_px: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    P1n = normalize_camera_matrix(as_array(P1, "P1", (3, 4)))
    P2n = normalize_camera_matrix(as_array(P2, "P2", (3, 4)))
    q1 = as_rows(q1_px, "q1_px", 2)
    q2 = as_rows(q2_px, "q2_px", 2)
    if q1.shape[0] != q2.shape[0]:
        raise InputError(
            f"q1_px and q2_px: expected the same number of points, got {q1.shape[0]} and "
            f"{q2.shape[0]}"
        )
    return P1n, P2n, q1, q2


def _linear(
    Ps: tuple[FloatArray, ...], qs: tuple[FloatArray, ...], seen: FloatArray | None = None
) -> FloatArray:
    """Linear triangulation over any number of views (Eq 3.18 stacked), (N, 3).

    ``seen`` (V, N) of 0 or 1 leaves a view's two equations out of a point's system; the
    pixels of a view not seen must be finite (any value).
    """
    # Rows of the equations: (x, y) of each view times the third row of its P, minus the
    # first or second row. Arrays are laid out (column, row, point) so that every operation
    # runs over contiguous memory.
    n = qs[0].shape[0]
    coords = np.empty((2 * len(qs), n))
    for v, q in enumerate(qs):
        coords[2 * v], coords[2 * v + 1] = q[:, 0], q[:, 1]
    third = np.stack([P[2] for P in Ps for _ in (0, 1)])  # (2V rows, 4 columns of P)
    first = np.stack([P[i] for P in Ps for i in (0, 1)])
    A = coords[None, :, :] * third.T[:3, :, None] - first.T[:3, :, None]
    b = first[:, 3:4] - coords * third[:, 3:4]
    if seen is not None:
        rows = np.repeat(seen, 2, axis=0)
        A = A * rows[None]
        b = b * rows
    x, _ = _lstsq_columns(A, b)
    return np.ascontiguousarray(x.T)


def triangulate(
    P1: ArrayLike,
    P2: ArrayLike,
    q1_px: ArrayLike,
    q2_px: ArrayLike,
    *,
    method: Literal["linear", "optimal"] = "linear",
) -> FloatArray:
    """Reconstruct 3D points from their images in two calibrated views (thesis Eq 3.18).

    Parameters
    ----------
    P1, P2 : (3, 4) float
        Projection matrices of the two cameras (world in µm), pinhole or affine
        (``P[2, :3] = 0``); any scale and sign.
    q1_px, q2_px : (N, 2) or (2,) float
        Undistorted pixel coordinates of the same N points in view 1 and view 2.
    method : {"linear", "optimal"}
        ``"linear"``: the DLT equations of Eq 3.18 by least squares. ``"optimal"``: minimise
        the reprojection error in both images (:func:`triangulate_optimal`).

    Returns
    -------
    p_um : (N, 3) float
        Points in the world frame, µm.
    """
    if method == "optimal":
        return triangulate_optimal(P1, P2, q1_px, q2_px)
    if method != "linear":
        raise InputError(f"method: expected 'linear' or 'optimal', got {method!r}")
    P1n, P2n, q1, q2 = _check_pair(P1, P2, q1_px, q2_px)
    return _linear((P1n, P2n), (q1, q2))


def _whitening(cov: ArrayLike | float | None, n: int, name: str) -> FloatArray:
    """Inverse Cholesky factors W (N, 2, 2) with ``W cov W^T = I``."""
    if cov is None:
        c = np.broadcast_to(np.eye(2), (n, 2, 2))
    elif np.ndim(cov) == 0:
        sigma = float(cov)  # type: ignore[arg-type]
        if not sigma > 0:
            raise InputError(f"{name}: expected a positive pixel standard deviation, got {sigma}")
        c = np.broadcast_to(np.eye(2) * sigma**2, (n, 2, 2))
    else:
        arr = np.asarray(cov, dtype=np.float64)
        if arr.shape == (2, 2):
            arr = np.broadcast_to(arr, (n, 2, 2))
        c = as_array(arr, name, (n, 2, 2))
    a = c[:, 0, 0]
    off = c[:, 1, 0]
    with np.errstate(invalid="ignore"):
        l00 = np.sqrt(a)
        l10 = off / l00
        l11 = np.sqrt(c[:, 1, 1] - l10**2)
    if not (np.all(l00 > 0) and np.all(l11 > 0)):
        raise InputError(f"{name}: expected positive definite 2x2 pixel covariances")
    W = np.zeros((n, 2, 2))
    W[:, 0, 0] = 1.0 / l00
    W[:, 1, 1] = 1.0 / l11
    W[:, 1, 0] = -l10 / (l00 * l11)
    return W


def _project_with_jacobian(P: FloatArray, p: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Projection of (N, 3) points by P: pixels (N, 2) and d q / d p (N, 2, 3).

    For an affine P (``P[2] = (0, 0, 0, 1)``) ``w = 1`` and this is ``P[:2] [p; 1]``.
    """
    h = p @ P[:, :3].T + P[:, 3]
    w = h[:, 2]
    q = h[:, :2] / w[:, None]
    jac = (P[None, :2, :3] - q[:, :, None] * P[None, 2:3, :3]) / w[:, None, None]
    return q, jac


def _whitened_system(
    Ps: tuple[FloatArray, ...],
    qs: tuple[FloatArray, ...],
    Ws: tuple[FloatArray, ...],
    p: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Whitened residuals (2V, N) and Jacobian (3, 2V, N) of the V views' reprojections (a
    view a point is not seen in has W = 0 there)."""
    res = []
    jac = []
    for P, q, W in zip(Ps, qs, Ws, strict=True):
        proj, J = _project_with_jacobian(P, p)
        res.append(np.einsum("nij,nj->in", W, proj - q))
        jac.append(np.einsum("nij,njk->kin", W, J))
    return np.concatenate(res, axis=0), np.concatenate(jac, axis=1)


def triangulate_optimal(
    P1: ArrayLike,
    P2: ArrayLike,
    q1_px: ArrayLike,
    q2_px: ArrayLike,
    cov1_px2: ArrayLike | float | None = None,
    cov2_px2: ArrayLike | float | None = None,
    *,
    max_iter: int = 10,
    rtol: float = 1e-13,
) -> FloatArray:
    """Triangulate by minimising the weighted reprojection error in both images.

    Parameters
    ----------
    P1, P2 : (3, 4) float
        Projection matrices (world in µm), pinhole or affine; any scale and sign.
    q1_px, q2_px : (N, 2) or (2,) float
        Undistorted pixel coordinates.
    cov1_px2, cov2_px2 : None, float, (2, 2) or (N, 2, 2)
        Pixel noise of each view: None (equal weights), a standard deviation in px, or
        covariance matrices in px². Only their ratio between the views matters here.
    max_iter : int
        Gauss-Newton iterations at most.
    rtol : float
        Stop when every step is below ``rtol`` times the point's distance from the origin
        plus one micrometre.

    Returns
    -------
    p_um : (N, 3) float
        Points in the world frame, µm.
    """
    P1n, P2n, q1, q2 = _check_pair(P1, P2, q1_px, q2_px)
    n = q1.shape[0]
    Ws = (_whitening(cov1_px2, n, "cov1_px2"), _whitening(cov2_px2, n, "cov2_px2"))
    p = _linear((P1n, P2n), (q1, q2))
    return _gauss_newton((P1n, P2n), (q1, q2), Ws, p, max_iter, rtol)


def _gauss_newton(
    Ps: tuple[FloatArray, ...],
    qs: tuple[FloatArray, ...],
    Ws: tuple[FloatArray, ...],
    p: FloatArray,
    max_iter: int,
    rtol: float,
) -> FloatArray:
    """Gauss-Newton on the whitened reprojection errors from ``p`` (N, 3), each point taking
    only the steps that lower its cost."""
    res, jac = _whitened_system(Ps, qs, Ws, p)
    cost = np.einsum("in,in->n", res, res)
    active = np.ones(p.shape[0], dtype=bool)
    for _ in range(max_iter):
        step, _ = _lstsq_columns(jac, -res)
        trial = p + step.T
        new_res, new_jac = _whitened_system(Ps, qs, Ws, trial)
        new_cost = np.einsum("in,in->n", new_res, new_res)
        better = active & (new_cost <= cost)
        p[better] = trial[better]
        res[:, better] = new_res[:, better]
        jac[:, :, better] = new_jac[:, :, better]
        cost[better] = new_cost[better]
        small = np.abs(step).max(axis=0) <= rtol * (np.abs(p).max(axis=1) + 1.0)
        active &= better & ~small
        if not active.any():
            break
    return p


def triangulation_covariance(
    P1: ArrayLike,
    P2: ArrayLike,
    p_um: ArrayLike,
    cov1_px2: ArrayLike | float,
    cov2_px2: ArrayLike | float,
) -> FloatArray:
    """Covariance of optimally triangulated points, by first-order propagation.

    ``Sigma_p = (J^T Sigma_q^-1 J)^-1`` with J the (4, 3) Jacobian of both views'
    projections at the point: the Cramér-Rao bound, which the optimal triangulation attains
    to first order.

    Parameters
    ----------
    P1, P2 : (3, 4) float
        Projection matrices (world in µm), pinhole or affine; any scale and sign.
    p_um : (N, 3) or (3,) float
        Triangulated points, µm.
    cov1_px2, cov2_px2 : float, (2, 2) or (N, 2, 2)
        Pixel noise of each view: a standard deviation in px, or covariances in px².

    Returns
    -------
    cov_um2 : (N, 3, 3) float
        Covariance of each point in µm².
    """
    P1n = normalize_camera_matrix(as_array(P1, "P1", (3, 4)))
    P2n = normalize_camera_matrix(as_array(P2, "P2", (3, 4)))
    p = as_rows(p_um, "p_um", 3)
    n = p.shape[0]
    if cov1_px2 is None or cov2_px2 is None:
        raise InputError("cov1_px2, cov2_px2: expected pixel noise for both views, got None")
    Ws = (_whitening(cov1_px2, n, "cov1_px2"), _whitening(cov2_px2, n, "cov2_px2"))
    zeros = np.zeros((n, 2))
    _, jac = _whitened_system((P1n, P2n), (zeros, zeros), Ws, p)
    _, Rinv = _lstsq_columns(jac, np.zeros((4, n)), with_rinv=True)
    assert Rinv is not None
    out: FloatArray = np.einsum("ikn,jkn->nij", Rinv, Rinv)
    return out


def triangulate_cameras(
    camera1: CameraModelProtocol,
    camera2: CameraModelProtocol,
    q1_px: ArrayLike,
    q2_px: ArrayLike,
    cov1_px2: ArrayLike | float,
    cov2_px2: ArrayLike | float,
) -> tuple[FloatArray, FloatArray]:
    """Optimal triangulation with its covariance, from two camera models.

    The cameras are used through :class:`~.camera_protocol.CameraModelProtocol` only (their
    ``P``), so every kind of camera model is triangulated alike. The same as
    :func:`triangulate_optimal` and :func:`triangulation_covariance` on ``camera1.P`` and
    ``camera2.P``, number for number.

    Parameters
    ----------
    camera1, camera2 : CameraModelProtocol
        The two calibrated cameras, in one world frame {G}.
    q1_px, q2_px : (N, 2) or (2,) float
        Undistorted pixels (as ``camera.undistort_px`` gives them) of the same N points.
    cov1_px2, cov2_px2 : float, (2, 2) or (N, 2, 2)
        Pixel noise of each view: a standard deviation in px, or covariances in px².

    Returns
    -------
    p_um : (N, 3) float
        Points in {G}, µm.
    cov_um2 : (N, 3, 3) float
        Their covariances, µm².
    """
    P1 = check_camera_model(camera1, "camera1").P
    P2 = check_camera_model(camera2, "camera2").P
    p = triangulate_optimal(P1, P2, q1_px, q2_px, cov1_px2, cov2_px2)
    return p, triangulation_covariance(P1, P2, p, cov1_px2, cov2_px2)


def triangulate_views(
    cameras: Sequence[CameraModelProtocol],
    q_px: Sequence[ArrayLike],
    cov_px2: Sequence[ArrayLike | float],
    *,
    max_iter: int = 10,
    rtol: float = 1e-13,
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """Optimal triangulation with its covariance from any number of views, any kind each.

    A point may be missing from some views (NaN pixels there): it is triangulated from the
    views that saw it, and its covariance counts only those. A point seen by fewer than two
    views is NaN. With two views seeing every point this is :func:`triangulate_cameras`.

    Parameters
    ----------
    cameras : sequence of V CameraModelProtocol
        The calibrated cameras, in one world frame {G}; pinhole and affine may be mixed.
    q_px : sequence of V (N, 2) float
        Undistorted pixels of the same N points in each view; a row of NaN where the view
        did not see the point.
    cov_px2 : sequence of V (float, (2, 2) or (N, 2, 2))
        Pixel noise of each view: a standard deviation in px, or covariances in px² (a
        missing point's entry is ignored).
    max_iter, rtol
        As :func:`triangulate_optimal`.

    Returns
    -------
    p_um : (N, 3) float
        Points in {G}, µm; NaN where fewer than two views saw the point.
    cov_um2 : (N, 3, 3) float
        Their covariances (the Cramér-Rao bound of the views that saw each), µm².
    n_views : (N,) int
        How many views saw each point.

    Raises
    ------
    InputError
        Fewer than two cameras, or pixel arrays of different lengths.
    """
    if len(cameras) < 2 or len(cameras) != len(q_px) or len(cameras) != len(cov_px2):
        raise InputError(
            f"cameras, q_px, cov_px2: expected one entry each for two or more cameras, got "
            f"{len(cameras)}, {len(q_px)} and {len(cov_px2)}"
        )
    Ps = tuple(
        normalize_camera_matrix(check_camera_model(c, f"cameras[{i}]").P)
        for i, c in enumerate(cameras)
    )
    qs = [as_rows(q, f"q_px[{i}]", 2, finite=False) for i, q in enumerate(q_px)]
    n = qs[0].shape[0]
    if any(q.shape[0] != n for q in qs):
        raise InputError(
            f"q_px: expected the same number of points in every view, got "
            f"{[q.shape[0] for q in qs]}"
        )
    seen = np.array([np.all(np.isfinite(q), axis=1) for q in qs])  # (V, N)
    n_views = seen.sum(axis=0).astype(np.int64)
    p = np.full((n, 3), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    ok = n_views >= 2
    if not ok.any():
        return p, cov, n_views
    sub = seen[:, ok]
    q_ok = tuple(np.where(s[:, None], q[ok], 0.0) for q, s in zip(qs, sub, strict=True))
    Ws = tuple(
        _masked_whitening(c, q_ok[0].shape[0], s, f"cov_px2[{i}]", ok)
        for i, (c, s) in enumerate(zip(cov_px2, sub, strict=True))
    )
    p_ok = _linear(Ps, q_ok, sub.astype(np.float64))
    p_ok = _gauss_newton(Ps, q_ok, Ws, p_ok, max_iter, rtol)
    zeros = tuple(np.zeros_like(q) for q in q_ok)
    _, jac = _whitened_system(Ps, zeros, Ws, p_ok)
    _, Rinv = _lstsq_columns(jac, np.zeros((2 * len(Ps), p_ok.shape[0])), with_rinv=True)
    assert Rinv is not None
    p[ok] = p_ok
    cov[ok] = np.einsum("ikn,jkn->nij", Rinv, Rinv)
    return p, cov, n_views


def _masked_whitening(
    cov: ArrayLike | float, n: int, seen: NDArray[np.bool_], name: str, keep: NDArray[np.bool_]
) -> FloatArray:
    """Whitening of one view for the points ``keep`` selects, W = 0 where it did not see one."""
    if np.ndim(cov) == 3:
        arr = np.array(cov, dtype=np.float64)
        if arr.shape[0] != keep.shape[0]:
            raise InputError(f"{name}: expected {keep.shape[0]} covariances, got {arr.shape[0]}")
        arr = arr[keep]
        arr[~seen] = np.eye(2)
        cov = arr
    W = _whitening(cov, n, name).copy()
    W[~seen] = 0.0
    return W
