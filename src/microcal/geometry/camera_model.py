"""The pinhole camera with lens distortion of thesis Eq 3.3-3.6.

A point ``p`` in the world frame (µm) goes to the camera frame by ``c = R p + t``, to
normalised image coordinates ``(x, y) = (c_x / c_z, c_y / c_z)``, through the lens distortion,
and to pixels by the intrinsic matrix ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]``. Without
distortion this is ``q ~ P [p; 1]`` with ``P = K [R | t]`` (Eq 3.6).

The lens distortion is OpenCV's, with its coefficients in its order
``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tau_x, tau_y]]]]`` (4, 5, 8, 12 or 14 of
them). With ``r2 = x^2 + y^2``:

- radial (rational with 8 or more): ``(1 + k1 r2 + k2 r4 + k3 r6) / (1 + k4 r2 + k5 r4 + k6 r6)``
  multiplies ``(x, y)``;
- tangential: ``x += 2 p1 x y + p2 (r2 + 2 x^2)``, ``y += p1 (r2 + 2 y^2) + 2 p2 x y``;
- thin prism (12 or more): ``x += s1 r2 + s2 r4``, ``y += s3 r2 + s4 r4``;
- tilted sensor (14): the distorted point goes through the homography of OpenCV's
  ``computeTiltProjectionMatrix`` (rotations about x by tau_x and about y by tau_y, then the
  projection matrix OpenCV builds from their product) before K.

The thesis's cameras use the first five (the thesis's Eq 3.3-3.5).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows
from ..errors import InputError

__all__ = [
    "DIST_LENGTHS",
    "CameraModel",
    "distort_normalized",
    "tilt_matrix",
    "undistort_normalized",
    "validate_camera_fields",
]

_ORTHONORMAL_TOL = 1e-9

#: The numbers of distortion coefficients OpenCV's models have; 4 is stored as 5.
DIST_LENGTHS = (4, 5, 8, 12, 14)
_DIST_ORDER = "k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tau_x, tau_y]]]]"


def _dist_expected(lengths: tuple[int, ...]) -> str:
    counts = ", ".join(str(n) for n in lengths[:-1]) + f" or {lengths[-1]}"
    return f"{counts} coefficients ({_DIST_ORDER})"


def _as_dist(value: ArrayLike) -> FloatArray:
    """The distortion coefficients as a float array of an OpenCV length; 4 padded to 5."""
    try:
        dist = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(
            f"dist: expected {_dist_expected(DIST_LENGTHS)}, got {type(value).__name__}"
        ) from None
    if dist.ndim != 1 or dist.shape[0] not in DIST_LENGTHS:
        got = f"{dist.shape[0]}" if dist.ndim == 1 else f"shape {dist.shape}"
        raise InputError(f"dist: expected {_dist_expected(DIST_LENGTHS)}, got {got}")
    if dist.shape == (4,):
        dist = np.append(dist, 0.0)
    return as_array(dist, "dist", dist.shape)


def tilt_matrix(tau_x: float, tau_y: float) -> FloatArray:
    """The homography of a tilted sensor, as OpenCV's ``computeTiltProjectionMatrix``.

    Parameters
    ----------
    tau_x, tau_y : float
        The sensor's tilt about the x and the y axis, rad.

    Returns
    -------
    H : (3, 3) float
        ``[x_t, y_t, w] = H [x_d, y_d, 1]`` takes a distorted normalised point to the tilted
        sensor's ``(x_t / w, y_t / w)``; the identity for no tilt.
    """
    c_x, s_x = np.cos(tau_x), np.sin(tau_x)
    c_y, s_y = np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, c_x, s_x], [0.0, -s_x, c_x]])
    rot_y = np.array([[c_y, 0.0, -s_y], [0.0, 1.0, 0.0], [s_y, 0.0, c_y]])
    rot_xy = rot_y @ rot_x
    proj_z = np.array(
        [
            [rot_xy[2, 2], 0.0, -rot_xy[0, 2]],
            [0.0, rot_xy[2, 2], -rot_xy[1, 2]],
            [0.0, 0.0, 1.0],
        ]
    )
    return np.asarray(proj_z @ rot_xy, dtype=np.float64)


def distort_normalized(xy: FloatArray, dist: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Apply the lens distortion to normalised image coordinates.

    Parameters
    ----------
    xy : (N, 2) float
        Ideal normalised coordinates (x, y) = (c_x / c_z, c_y / c_z).
    dist : (5,), (8,), (12,) or (14,) float
        OpenCV's coefficients in its order: k1, k2, p1, p2, k3, then k4, k5, k6 (rational
        radial), then s1, s2, s3, s4 (thin prism), then tau_x, tau_y (tilted sensor, rad).

    Returns
    -------
    xy_d : (N, 2) float
        Distorted normalised coordinates (on the tilted sensor with 14 coefficients).
    jac : (N, 2, 2) float
        d xy_d / d xy.

    Raises
    ------
    InputError
        ``dist`` has another number of coefficients.
    """
    n_coef = len(dist)
    if n_coef not in DIST_LENGTHS[1:]:
        raise InputError(f"dist: expected {_dist_expected(DIST_LENGTHS[1:])}, got {n_coef}")
    k1, k2, p1, p2, k3 = dist[:5]
    x = xy[:, 0]
    y = xy[:, 1]
    xx, yy, xy_ = x * x, y * y, x * y
    r2 = xx + yy
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    if n_coef >= 8:  # rational radial: divide by 1 + k4 r2 + k5 r4 + k6 r6
        k4, k5, k6 = dist[5:8]
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
        radial = radial / den
        dradial = (dradial - radial * dden) / den
    out = np.empty_like(xy)
    out[:, 0] = x * radial + 2.0 * p1 * xy_ + p2 * (r2 + 2.0 * xx)
    out[:, 1] = y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy_
    jac = np.empty((xy.shape[0], 2, 2))
    cross = 2.0 * xy_ * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    jac[:, 0, 0] = radial + 2.0 * xx * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    jac[:, 0, 1] = cross
    jac[:, 1, 0] = cross
    jac[:, 1, 1] = radial + 2.0 * yy * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    if n_coef >= 12:  # thin prism
        s1, s2, s3, s4 = dist[8:12]
        r4 = r2 * r2
        out[:, 0] += s1 * r2 + s2 * r4
        out[:, 1] += s3 * r2 + s4 * r4
        gx = 2.0 * (s1 + 2.0 * s2 * r2)  # d (s1 r2 + s2 r4) / d r2, times 2
        gy = 2.0 * (s3 + 2.0 * s4 * r2)
        jac[:, 0, 0] += gx * x
        jac[:, 0, 1] += gx * y
        jac[:, 1, 0] += gy * x
        jac[:, 1, 1] += gy * y
    if n_coef == 14:  # tilted sensor: the homography of OpenCV's computeTiltProjectionMatrix
        H = tilt_matrix(float(dist[12]), float(dist[13]))
        xd0 = out[:, 0].copy()
        yd0 = out[:, 1].copy()
        inv_w = 1.0 / (H[2, 0] * xd0 + H[2, 1] * yd0 + H[2, 2])
        out[:, 0] = (H[0, 0] * xd0 + H[0, 1] * yd0 + H[0, 2]) * inv_w
        out[:, 1] = (H[1, 0] * xd0 + H[1, 1] * yd0 + H[1, 2]) * inv_w
        tilt = np.empty_like(jac)  # d out / d (xd0, yd0)
        for i in range(2):
            for j in range(2):
                tilt[:, i, j] = (H[i, j] - out[:, i] * H[2, j]) * inv_w
        jac = tilt @ jac
    return out, jac


def undistort_normalized(
    xy_d: FloatArray,
    dist: FloatArray,
    scale_px: FloatArray,
    *,
    tol_px: float = 1e-6,
    max_iter: int = 30,
) -> FloatArray:
    """Invert :func:`distort_normalized` by Newton's method, vectorised over points.

    Parameters
    ----------
    xy_d : (N, 2) float
        Distorted normalised coordinates.
    dist : (5,), (8,), (12,) or (14,) float
        The coefficients of :func:`distort_normalized`.
    scale_px : (2, 2) float
        The linear part of K (``[[fx, s], [0, fy]]``): the convergence test is done in pixels.
    tol_px : float
        Stop a point when re-distorting it lands within ``tol_px`` pixels of the input.
    max_iter : int
        Newton iterations at most.

    Returns
    -------
    xy : (N, 2) float
        Ideal normalised coordinates; NaN where Newton's method did not converge (far outside
        the image, where a strong distortion model folds over).
    """
    xy = xy_d.copy()
    active = np.ones(xy.shape[0], dtype=bool)
    for _ in range(max_iter):
        if not active.any():
            break
        cur = xy[active]
        fwd, jac = distort_normalized(cur, dist)
        res = fwd - xy_d[active]
        err_px = np.abs(res @ scale_px.T).max(axis=1)
        done = err_px <= tol_px
        det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            step_x = (jac[:, 1, 1] * res[:, 0] - jac[:, 0, 1] * res[:, 1]) / det
            step_y = (jac[:, 0, 0] * res[:, 1] - jac[:, 1, 0] * res[:, 0]) / det
        # The step is taken by converged points too: Newton's quadratic convergence then
        # leaves them far below the tolerance on the ideal side as well.
        cur[:, 0] -= step_x
        cur[:, 1] -= step_y
        xy[active] = cur
        idx = np.flatnonzero(active)
        active[idx[done]] = False
    if active.any():
        # One last check for the points whose final step converged.
        idx = np.flatnonzero(active)
        fwd, _ = distort_normalized(xy[idx], dist)
        err_px = np.abs((fwd - xy_d[idx]) @ scale_px.T).max(axis=1)
        bad = idx[~(err_px <= tol_px)]
        xy[bad] = np.nan
    return xy


def validate_camera_fields(cam: Any, positive: str, x_name: str, y_name: str) -> None:
    """Check and freeze the fields K, dist, R, t_um, image_size_px and projection_sigma_px
    that every camera kind has (a frozen dataclass, set in place).

    ``positive`` names what K's diagonal must be (``"fx > 0 and fy > 0"``), ``x_name`` and
    ``y_name`` its two entries in the message.
    """
    K = as_array(cam.K, "K", (3, 3))
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise InputError(f"K: expected upper triangular with K[2, 2] = 1, got rows {K.tolist()}")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"K: expected {positive}, got {x_name}={K[0, 0]}, {y_name}={K[1, 1]}")
    dist = _as_dist(cam.dist)
    R = as_array(cam.R, "R", (3, 3))
    ortho = float(np.abs(R @ R.T - np.eye(3)).max())
    if ortho > _ORTHONORMAL_TOL or np.linalg.det(R) < 0:
        raise InputError(
            f"R: expected a rotation (R R^T = I within {_ORTHONORMAL_TOL}, det +1), "
            f"got deviation {ortho:.2e} and det {np.linalg.det(R):+.6f}"
        )
    t = as_array(cam.t_um, "t_um", (3,))
    given = cam.image_size_px
    size = tuple(int(v) for v in given)
    if len(size) != 2 or min(size) <= 0 or max(size) > 1_000_000:
        raise InputError(f"image_size_px: expected (width, height) of 1 to 10^6 px, got {given}")
    for key, value in (("K", K), ("dist", dist), ("R", R), ("t_um", t)):
        value.setflags(write=False)
        object.__setattr__(cam, key, value)
    object.__setattr__(cam, "image_size_px", size)
    given_sigma = cam.projection_sigma_px
    sigma = float(given_sigma)
    if not (np.isfinite(sigma) and sigma >= 0):
        raise InputError(f"projection_sigma_px: expected a finite value >= 0, got {given_sigma}")
    object.__setattr__(cam, "projection_sigma_px", sigma)


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A calibrated camera: intrinsics, lens distortion and pose (thesis Eq 3.3-3.6).

    Parameters
    ----------
    K : (3, 3) float
        Intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels; fx, fy > 0.
    dist : (4,), (5,), (8,), (12,) or (14,) float
        Distortion in OpenCV's order, k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[,
        tau_x, tau_y]]]] (see :func:`distort_normalized`); 4 are stored as 5 (k3 = 0), the
        other lengths as given.
    R : (3, 3) float
        Rotation from the world frame {G} into the camera frame; orthonormal, det +1.
    t_um : (3,) float
        Translation in µm: a world point ``p`` is at ``R p + t_um`` in the camera frame.
    image_size_px : (int, int)
        Image width and height in pixels.
    name : str
        Free name of the camera ("top", "side", "left" ...).
    projection_sigma_px : float
        1-sigma error, per image axis, of this camera's projections that comes from its
        calibration (not from the image): the same for every frame, so averaging frames does
        not lower it. 0 when unknown. Measurement adds it to each virtual point's covariance.

    Notes
    -----
    Implements :class:`~microcal.geometry.camera_protocol.CameraModelProtocol` with
    ``kind == "pinhole"``.
    """

    #: The model's kind, as cameras.json's ``"model"`` key spells it.
    kind: ClassVar[str] = "pinhole"

    K: FloatArray
    dist: FloatArray
    R: FloatArray
    t_um: FloatArray
    image_size_px: tuple[int, int]
    name: str = field(default="camera")
    projection_sigma_px: float = 0.0

    def __post_init__(self) -> None:
        validate_camera_fields(self, "fx > 0 and fy > 0", "fx", "fy")

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_projection_matrix(
        cls,
        P: ArrayLike,
        image_size_px: tuple[int, int],
        dist: ArrayLike | None = None,
        name: str = "camera",
    ) -> CameraModel:
        """Build a camera from a 3x4 projection matrix (world in µm) by RQ decomposition.

        Parameters
        ----------
        P : (3, 4) float
            Projection matrix, any scale and sign.
        image_size_px : (int, int)
            Width and height.
        dist : (4,), (5,), (8,), (12,) or (14,) float, optional
            Distortion in OpenCV's order, as the class takes it; five zeros by default.
        """
        from .projection_matrix import decompose_projection_matrix

        K, R, t = decompose_projection_matrix(P)
        K = K.copy()
        K[1, 0] = K[2, 0] = K[2, 1] = 0.0
        K[2, 2] = 1.0
        return cls(
            K, np.zeros(5) if dist is None else np.asarray(dist, float), R, t, image_size_px, name
        )

    # --- derived quantities -------------------------------------------------------------
    @property
    def P(self) -> FloatArray:
        """(3, 4) projection matrix ``K [R | t]`` of the undistorted camera (world in µm)."""
        return np.asarray(self.K @ np.hstack([self.R, self.t_um[:, None]]), dtype=np.float64)

    @property
    def centre_um(self) -> FloatArray:
        """(3,) position of the projection centre in the world frame, µm."""
        return np.asarray(-self.R.T @ self.t_um, dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        """True if any distortion coefficient is non-zero."""
        return bool(np.any(self.dist != 0))

    def depth_um(self, p_um: ArrayLike) -> FloatArray:
        """(N,) depth of world points along the optical axis (``(R p + t)_z``), µm."""
        p = as_rows(p_um, "p_um", 3)
        return np.asarray(p @ self.R[2] + self.t_um[2], dtype=np.float64)

    def plane_to_ideal_px(self, R_plane: ArrayLike, t_plane_um: ArrayLike) -> FloatArray:
        """(3, 3) homography from a plane's (u, v, 1) in µm to ideal pixels.

        The plane's point (u, v) is at ``R_plane [u, v, 0] + t_plane_um`` in {G}:
        ``K [r1 r2 t]`` with ``r1``, ``r2`` the plane's axes and ``t`` its origin in the camera
        frame.
        """
        Rp = as_array(R_plane, "R_plane", (3, 3))
        tp = as_array(t_plane_um, "t_plane_um", (3,))
        RR = self.R @ Rp
        return np.asarray(
            self.K @ np.column_stack([RR[:, 0], RR[:, 1], self.R @ tp + self.t_um]),
            dtype=np.float64,
        )

    # --- projection ---------------------------------------------------------------------
    def _to_normalized(self, p: FloatArray) -> tuple[FloatArray, FloatArray]:
        c = p @ self.R.T + self.t_um
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = c[:, :2] / c[:, 2:3]
        return xy, c

    def _to_pixels(self, xy: FloatArray) -> FloatArray:
        K = self.K
        q = np.empty_like(xy)
        q[:, 0] = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
        q[:, 1] = K[1, 1] * xy[:, 1] + K[1, 2]
        return q

    def project(self, p_um: ArrayLike, *, distort: bool = True) -> FloatArray:
        """Project world points into the image.

        Parameters
        ----------
        p_um : (N, 3) or (3,) float
            Points in the world frame {G}, µm.
        distort : bool
            Apply the lens distortion (the real camera) or not (the ideal pinhole ``P``).

        Returns
        -------
        q_px : (N, 2) float
            Pixel coordinates (x, y). Points at or behind the projection centre give NaN.
        """
        p = as_rows(p_um, "p_um", 3)
        xy, c = self._to_normalized(p)
        if distort and self.has_distortion:
            xy, _ = distort_normalized(xy, self.dist)
        q = self._to_pixels(xy)
        q[c[:, 2] <= 0] = np.nan
        return q

    def project_jacobian(self, p_um: ArrayLike, *, distort: bool = True) -> FloatArray:
        """Derivative of :meth:`project` with respect to the world point.

        Parameters
        ----------
        p_um : (N, 3) or (3,) float
            Points in {G}, µm.

        Returns
        -------
        jac : (N, 2, 3) float
            d q_px / d p_um, pixels per µm.
        """
        p = as_rows(p_um, "p_um", 3)
        xy, c = self._to_normalized(p)
        n = p.shape[0]
        dxy_dc = np.zeros((n, 2, 3))
        inv_z = 1.0 / c[:, 2]
        dxy_dc[:, 0, 0] = inv_z
        dxy_dc[:, 1, 1] = inv_z
        dxy_dc[:, 0, 2] = -xy[:, 0] * inv_z
        dxy_dc[:, 1, 2] = -xy[:, 1] * inv_z
        jac = dxy_dc @ self.R
        if distort and self.has_distortion:
            _, djac = distort_normalized(xy, self.dist)
            jac = djac @ jac
        out: FloatArray = self.K[:2, :2] @ jac
        return out

    def undistort_px(
        self, q_px: ArrayLike, *, tol_px: float = 1e-6, max_iter: int = 30
    ) -> FloatArray:
        """Remove the lens distortion from observed pixels.

        Parameters
        ----------
        q_px : (N, 2) or (2,) float
            Observed (distorted) pixel coordinates.
        tol_px : float
            Convergence: re-distorting the result reproduces the input within ``tol_px``.
        max_iter : int
            Newton iterations at most.

        Returns
        -------
        q_ideal_px : (N, 2) float
            Pixels of the ideal pinhole camera ``P`` (same K, no distortion). NaN where the
            iteration did not converge (only far outside the image for sane distortion).
        """
        q = as_rows(q_px, "q_px", 2)
        if not self.has_distortion:
            return q.copy()
        A = self.K[:2, :2]
        xy_d = np.asarray(np.linalg.solve(A, (q - self.K[:2, 2]).T).T, dtype=np.float64)
        xy = undistort_normalized(xy_d, self.dist, A, tol_px=tol_px, max_iter=max_iter)
        return self._to_pixels(xy)

    def distort_px(self, q_ideal_px: ArrayLike) -> FloatArray:
        """Apply the lens distortion to ideal pinhole pixels (inverse of :meth:`undistort_px`).

        Parameters
        ----------
        q_ideal_px : (N, 2) or (2,) float

        Returns
        -------
        q_px : (N, 2) float
        """
        q = as_rows(q_ideal_px, "q_ideal_px", 2)
        if not self.has_distortion:
            return q.copy()
        A = self.K[:2, :2]
        xy = np.asarray(np.linalg.solve(A, (q - self.K[:2, 2]).T).T, dtype=np.float64)
        xy_d, _ = distort_normalized(xy, self.dist)
        return self._to_pixels(xy_d)

    def back_project(
        self, q_px: ArrayLike, *, distort: bool = True
    ) -> tuple[FloatArray, FloatArray]:
        """The rays of {G} that pixels come from.

        Parameters
        ----------
        q_px : (N, 2) or (2,) float
            Pixel coordinates.
        distort : bool
            The pixels carry the lens distortion (observed by the real camera; it is removed
            first by :meth:`undistort_px`) or not (pixels of the ideal pinhole ``P``), as in
            :meth:`project`.

        Returns
        -------
        origin_um : (N, 3) float
            The projection centre :attr:`centre_um`, in {G}, µm, once per pixel.
        direction : (N, 3) float
            Unit direction of each ray in {G}, towards the scene (positive depth): the points
            ``origin_um + s * direction``, ``s > 0``, project onto ``q_px``. NaN where the
            undistortion did not converge.
        """
        q = as_rows(q_px, "q_px", 2)
        if distort and self.has_distortion:
            q = self.undistort_px(q)
        A = self.K[:2, :2]
        xy = np.linalg.solve(A, (q - self.K[:2, 2]).T).T
        ray_c = np.hstack([xy, np.ones((q.shape[0], 1))])
        ray_c /= np.linalg.norm(ray_c, axis=1, keepdims=True)
        direction = np.asarray(ray_c @ self.R, dtype=np.float64)  # R^T d, row by row
        origin = np.asarray(np.broadcast_to(self.centre_um, direction.shape), dtype=np.float64)
        return origin.copy(), direction

    def __repr__(self) -> str:
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        w, h = self.image_size_px
        return (
            f"CameraModel(name={self.name!r}, {w}x{h} px, fx={fx:.1f}, fy={fy:.1f}, "
            f"cx={cx:.1f}, cy={cy:.1f}, dist={np.round(self.dist, 6).tolist()})"
        )
