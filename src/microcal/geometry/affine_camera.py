"""The affine camera: parallel projection with scale (telecentric lens, weak perspective).

An object-side telecentric lens images every point along rays parallel to its axis, so the
image does not change with depth; a long-focus microscope objective whose depth range is
small against its working distance is close to that (weak perspective). A world point ``p``
(µm) goes to the camera frame by ``c = R p + t`` (as the pinhole camera's), and its ideal
pixel is

    q_ideal = A [c_x, c_y, 1],   A = K[:2] = [[mx, s, cx], [0, my, cy]]

with ``mx``, ``my`` the magnification in px/µm (a 0.5x lens on 4.4 µm pixels: 0.114 px/µm)
and ``(cx, cy)`` the principal point, the centre of the lens distortion. The depth ``c_z``
does not enter the image; ``t_um[2]`` is the depth of the world origin along the axis (the
working distance), kept for the depth of field and for the rays' origins only. Without
distortion this is ``q ~ P [p; 1]`` with ``P = [[A[:, :2] R[:2], A[:, :2] t[:2] + (cx, cy)],
[0, 0, 0, 1]]``: ``P[2, :3] = 0`` marks the affine camera everywhere in microcal.

The lens distortion is OpenCV's (its coefficients in its order, as
:class:`~microcal.geometry.camera_model.CameraModel` takes them), applied to the ideal image
coordinates relative to the principal point in units of half the image diagonal:
``xy = (q_ideal - (cx, cy)) / r_px``, ``r_px = hypot(w, h) / 2``. A coefficient then reads
directly as a fraction of the field: ``k1 = 1e-3`` moves an image corner outward by 0.1 % of
its radius, the size telecentric lenses are sold with.

The principal point and the translation across the axis trade off exactly without
distortion (only ``A[:, :2] t[:2] + (cx, cy)`` is seen); a calibration fixes the principal
point at the image centre unless it fits a distortion.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows
from ..errors import InputError
from .camera_model import distort_normalized, undistort_normalized, validate_camera_fields

__all__ = ["AffineCamera", "distortion_radius_px"]


def distortion_radius_px(image_size_px: tuple[int, int]) -> float:
    """Half the image diagonal, the unit of an affine camera's distortion coordinates (px)."""
    w, h = image_size_px
    return float(np.hypot(w, h) / 2.0)


@dataclass(frozen=True, eq=False)
class AffineCamera:
    """A calibrated affine (telecentric) camera: magnification, distortion and pose.

    Parameters
    ----------
    K : (3, 3) float
        ``[[mx, s, cx], [0, my, cy], [0, 0, 1]]``: magnification in px/µm (mx, my > 0), skew
        and principal point in px.
    dist : (4,), (5,), (8,), (12,) or (14,) float
        Distortion in OpenCV's order on the coordinates of the module docstring.
    R : (3, 3) float
        Rotation from {G} into the camera frame (its z axis along the lens axis, towards the
        scene); orthonormal, det +1.
    t_um : (3,) float
        Translation, µm: a world point ``p`` is at ``R p + t_um`` in the camera frame.
        ``t_um[2]`` is not seen in the image (the working distance).
    image_size_px : (int, int)
        Width and height in pixels.
    name : str
        Free name of the camera.
    projection_sigma_px : float
        1-sigma error per image axis of this camera's projections that comes from its
        calibration (the same for every frame); 0 when unknown.

    Notes
    -----
    Implements :class:`~microcal.geometry.camera_protocol.CameraModelProtocol` with
    ``kind == "affine"``.
    """

    #: The model's kind, as cameras.json's ``"model"`` key spells it.
    kind: ClassVar[str] = "affine"

    K: FloatArray
    dist: FloatArray
    R: FloatArray
    t_um: FloatArray
    image_size_px: tuple[int, int]
    name: str = field(default="camera")
    projection_sigma_px: float = 0.0

    def __post_init__(self) -> None:
        validate_camera_fields(self, "magnifications mx > 0 and my > 0 px/µm", "mx", "my")

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_projection_matrix(
        cls,
        P: ArrayLike,
        image_size_px: tuple[int, int],
        dist: ArrayLike | None = None,
        name: str = "camera",
        *,
        principal_point_px: ArrayLike | None = None,
        depth_um: float = 0.0,
    ) -> AffineCamera:
        """An affine camera from its 3x4 matrix (``P[2] = (0, 0, 0, c)``, any scale ``c``).

        The 2x3 part is split into an upper triangular magnification with a positive
        diagonal and two orthonormal rows of R (the third their cross product).

        Parameters
        ----------
        P : (3, 4) float
            Affine projection matrix, world in µm.
        image_size_px : (int, int)
        dist : (5,) float etc., optional
            Distortion; zeros by default.
        name : str
        principal_point_px : (2,) float, optional
            Where the principal point is (the distortion centre); the image centre by default.
        depth_um : float
            ``t_um[2]``, the unseen depth of the world origin.
        """
        P = as_array(P, "P", (3, 4))
        if np.any(P[2, :3] != 0) or P[2, 3] == 0:
            raise InputError(f"P: expected an affine matrix (third row (0, 0, 0, c)), got {P[2]}")
        M = P[:2] / P[2, 3]
        c2 = float(np.linalg.norm(M[1, :3]))
        if not c2 > 0:
            raise InputError("P: expected rank 2 in its first three columns, got a degenerate P")
        r2 = M[1, :3] / c2
        b = float(M[0, :3] @ r2)
        v = M[0, :3] - b * r2
        a = float(np.linalg.norm(v))
        if not a > 1e-12 * c2:
            raise InputError("P: expected rank 2 in its first three columns, got a degenerate P")
        r1 = v / a
        R = np.vstack([r1, r2, np.cross(r1, r2)])
        w, h = image_size_px
        centre = (
            np.array([(w - 1) / 2.0, (h - 1) / 2.0])
            if principal_point_px is None
            else as_array(principal_point_px, "principal_point_px", (2,))
        )
        A2 = np.array([[a, b], [0.0, c2]])
        t_xy = np.linalg.solve(A2, M[:, 3] - centre)
        K = np.array([[a, b, centre[0]], [0.0, c2, centre[1]], [0.0, 0.0, 1.0]])
        t = np.array([t_xy[0], t_xy[1], float(depth_um)])
        return cls(K, np.zeros(5) if dist is None else np.asarray(dist, float), R, t,
                   image_size_px, name)  # fmt: skip

    # --- derived quantities -------------------------------------------------------------
    @property
    def P(self) -> FloatArray:
        """(3, 4) affine projection matrix of the undistorted camera, ``P[2] = (0, 0, 0, 1)``."""
        A2 = self.K[:2, :2]
        top = np.hstack([A2 @ self.R[:2], (A2 @ self.t_um[:2] + self.K[:2, 2])[:, None]])
        return np.asarray(np.vstack([top, [0.0, 0.0, 0.0, 1.0]]), dtype=np.float64)

    @property
    def axis(self) -> FloatArray:
        """(3,) unit direction of the lens axis in {G}, towards the scene."""
        return np.asarray(self.R[2], dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        """True if any distortion coefficient is non-zero."""
        return bool(np.any(self.dist != 0))

    @property
    def radius_px(self) -> float:
        """Half the image diagonal: the unit of the distortion coordinates, px."""
        return distortion_radius_px(self.image_size_px)

    def depth_um(self, p_um: ArrayLike) -> FloatArray:
        """(N,) depth of world points along the lens axis (``(R p + t)_z``), µm."""
        p = as_rows(p_um, "p_um", 3)
        return np.asarray(p @ self.R[2] + self.t_um[2], dtype=np.float64)

    def plane_to_ideal_px(self, R_plane: ArrayLike, t_plane_um: ArrayLike) -> FloatArray:
        """(3, 3) homography from a plane's (u, v, 1) in µm to ideal pixels.

        The plane's point (u, v) is at ``R_plane [u, v, 0] + t_plane_um`` in {G}. Its last
        row is (0, 0, 1): parallel projection maps a plane affinely.
        """
        Rp = as_array(R_plane, "R_plane", (3, 3))
        tp = as_array(t_plane_um, "t_plane_um", (3,))
        P = self.P
        return np.asarray(
            np.vstack([np.column_stack([P[:2, :3] @ Rp[:, 0], P[:2, :3] @ Rp[:, 1],
                                        P[:2, :3] @ tp + P[:2, 3]]), [0.0, 0.0, 1.0]]),
            dtype=np.float64,
        )  # fmt: skip

    # --- projection ---------------------------------------------------------------------
    def _ideal(self, p: FloatArray) -> FloatArray:
        P = self.P
        return np.asarray(p @ P[:2, :3].T + P[:2, 3], dtype=np.float64)

    def _normalized(self, q_ideal: FloatArray) -> FloatArray:
        return np.asarray((q_ideal - self.K[:2, 2]) / self.radius_px, dtype=np.float64)

    def distort_px(self, q_ideal_px: ArrayLike) -> FloatArray:
        """Apply the lens distortion to ideal pixels (inverse of :meth:`undistort_px`).

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
        xy_d, _ = distort_normalized(self._normalized(q), self.dist)
        return np.asarray(xy_d * self.radius_px + self.K[:2, 2], dtype=np.float64)

    def project(self, p_um: ArrayLike, *, distort: bool = True) -> FloatArray:
        """Project world points into the image.

        Parameters
        ----------
        p_um : (N, 3) or (3,) float
            Points in {G}, µm.
        distort : bool
            Apply the lens distortion (the real camera) or not (the ideal affine ``P``).

        Returns
        -------
        q_px : (N, 2) float
            Pixel coordinates (x, y). Every point is seen: parallel projection has no centre.
        """
        q = self._ideal(as_rows(p_um, "p_um", 3))
        return self.distort_px(q) if distort else q

    def project_jacobian(self, p_um: ArrayLike, *, distort: bool = True) -> FloatArray:
        """Derivative of :meth:`project` with respect to the world point.

        Parameters
        ----------
        p_um : (N, 3) or (3,) float
            Points in {G}, µm.

        Returns
        -------
        jac : (N, 2, 3) float
            d q_px / d p_um, pixels per µm: ``D A[:, :2] R[:2]`` with D the distortion's
            2x2 derivative (the radius cancels).
        """
        p = as_rows(p_um, "p_um", 3)
        M = self.P[:2, :3]
        jac = np.broadcast_to(M, (p.shape[0], 2, 3))
        if distort and self.has_distortion:
            _, D = distort_normalized(self._normalized(self._ideal(p)), self.dist)
            return np.asarray(D @ M, dtype=np.float64)
        return np.asarray(jac, dtype=np.float64).copy()

    def undistort_px(
        self, q_px: ArrayLike, *, tol_px: float = 1e-6, max_iter: int = 30
    ) -> FloatArray:
        """Remove the lens distortion from observed pixels.

        Parameters
        ----------
        q_px : (N, 2) or (2,) float
            Observed pixel coordinates.
        tol_px : float
            Re-distorting the result reproduces the input within ``tol_px``.
        max_iter : int
            Newton iterations at most.

        Returns
        -------
        q_ideal_px : (N, 2) float
            Pixels of the ideal affine camera ``P``; NaN where the iteration did not converge.
        """
        q = as_rows(q_px, "q_px", 2)
        if not self.has_distortion:
            return q.copy()
        r = self.radius_px
        xy = undistort_normalized(self._normalized(q), self.dist, np.eye(2) * r,
                                  tol_px=tol_px, max_iter=max_iter)  # fmt: skip
        return np.asarray(xy * r + self.K[:2, 2], dtype=np.float64)

    def back_project(
        self, q_px: ArrayLike, *, distort: bool = True
    ) -> tuple[FloatArray, FloatArray]:
        """The rays of {G} that pixels come from: all parallel to the lens axis.

        Parameters
        ----------
        q_px : (N, 2) or (2,) float
            Pixel coordinates.
        distort : bool
            The pixels carry the lens distortion (removed first) or not.

        Returns
        -------
        origin_um : (N, 3) float
            The point of each ray at depth 0 in the camera frame, in {G}, µm.
        direction : (N, 3) float
            The lens axis in {G} (towards the scene), once per pixel; NaN where the
            undistortion did not converge.
        """
        q = as_rows(q_px, "q_px", 2)
        if distort and self.has_distortion:
            q = self.undistort_px(q)
        A2 = self.K[:2, :2]
        c_xy = np.linalg.solve(A2, (q - self.K[:2, 2]).T).T
        c = np.column_stack([c_xy, np.zeros(q.shape[0])])
        origin = np.asarray((c - self.t_um) @ self.R, dtype=np.float64)  # R^T (c - t)
        direction = np.broadcast_to(self.axis, origin.shape).copy()
        direction[~np.all(np.isfinite(origin), axis=1)] = np.nan
        return origin, direction

    def __repr__(self) -> str:
        mx, my, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        w, h = self.image_size_px
        return (
            f"AffineCamera(name={self.name!r}, {w}x{h} px, mx={mx:.5f}, my={my:.5f} px/µm, "
            f"cx={cx:.1f}, cy={cy:.1f}, dist={np.round(self.dist, 6).tolist()})"
        )
