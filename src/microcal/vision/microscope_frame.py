"""The microscope's frame {M}: a tip's image and focus reading as a point in µm.

A one-camera rig measures a tip as its image ``q`` (px) and the focus drive's reading ``f``
(µm) with the tip in focus. The camera's calibration against its X-Y stage
(:class:`~microcal.vision.stage_affine.ScopeCalibration`) says how the image moves per stage
µm (``M``, px/µm) and per µm of focus (``g``, px/µm). A point that is not on the stage is
placed in {M} as the stage position that would bring a slide's feature to the same image
at the same focus:

    x, y = M^-1 ((q - c) - g f),        z = f

with ``c`` the image centre: {M}'s x, y axes are the stage's (µm of stage travel, whatever
the camera's rotation, skew or mirror), its origin the field's centre at focus reading 0,
and its z the focus reading (µm of the drive; the drive's scale error is {M}'s, and the
fitted kinematics absorb it). The field's sideways travel along a tilted focus axis is taken
out by ``g f``. Distortion is left out: the map is the stage's linear one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..errors import InputError
from .stage_affine import ScopeCalibration

__all__ = ["MicroscopeFrame"]


@dataclass(frozen=True)
class MicroscopeFrame:
    """The map between (image px, focus reading µm) and {M} (µm); see the module docstring.

    Attributes
    ----------
    px_per_um : (2, 2) float
        ``M``: the image's displacement per stage µm.
    drift_px_per_um : (2,) float
        ``g``: the image's drift per µm of focus.
    centre_px : (2,) float
        The image centre ``c`` of the camera the tips are measured in.
    """

    px_per_um: FloatArray
    drift_px_per_um: FloatArray
    centre_px: FloatArray

    def __post_init__(self) -> None:
        m = np.asarray(self.px_per_um, dtype=np.float64)
        if m.shape != (2, 2) or not np.all(np.isfinite(m)) or abs(np.linalg.det(m)) < 1e-12:
            raise InputError("microscope frame: expected an invertible 2 x 2 map, px per µm")
        object.__setattr__(self, "px_per_um", m)
        object.__setattr__(self, "drift_px_per_um", np.asarray(self.drift_px_per_um, float))
        object.__setattr__(self, "centre_px", np.asarray(self.centre_px, float))

    @classmethod
    def from_scope(cls, scope: ScopeCalibration, image_size_px: tuple[int, int]) -> MicroscopeFrame:
        """The frame of a scope calibration on a camera of ``image_size_px`` (width, height):
        its stage map and drift (the calibration may have seen a smaller region of the
        same sensor; the linear map is the same)."""
        w, h = image_size_px
        m = np.asarray(-np.linalg.inv(np.asarray(scope.affine_um, dtype=np.float64)[:, :2]), float)
        centre = np.array([(w - 1) / 2, (h - 1) / 2])
        return cls(m, np.asarray(scope.drift_px_per_um, float), centre)

    @classmethod
    def from_record(
        cls, record: Mapping[str, object], image_size_px: tuple[int, int]
    ) -> MicroscopeFrame:
        """The frame of one objective's set of a scope file
        (:meth:`~microcal.vision.stage_affine.ScopeCalibration.to_json`'s object: its
        ``pixel_size_affine`` and ``focus.drift_px_per_um``) on a camera of ``image_size_px``;
        the same as :meth:`from_scope` of the calibration it was written from.

        Raises
        ------
        InputError
            A set without those keys, or with numbers of other shapes.
        """
        focus = record.get("focus")
        affine = record.get("pixel_size_affine")
        drift = focus.get("drift_px_per_um") if isinstance(focus, Mapping) else None
        try:
            a = np.asarray(affine, dtype=np.float64).reshape(2, 3)
            g = np.asarray(drift, dtype=np.float64).reshape(2)
        except (TypeError, ValueError):
            raise InputError(
                "scope set: expected pixel_size_affine (6 numbers) and focus.drift_px_per_um "
                "(2 numbers); calibrate the objective again (microcal scope-calibrate)"
            ) from None
        w, h = image_size_px
        m = np.asarray(-np.linalg.inv(a[:, :2]), dtype=np.float64)
        return cls(m, g, np.array([(w - 1) / 2, (h - 1) / 2]))

    @property
    def um_per_px(self) -> float:
        """The pixel's size in the object, ``sqrt(|det M^-1|)``, µm."""
        return float(np.sqrt(abs(np.linalg.det(np.linalg.inv(self.px_per_um)))))

    def jacobian(self) -> FloatArray:
        """d{M} / d(q_x, q_y, f), (3, 3) (the map is linear)."""
        inv = np.linalg.inv(self.px_per_um)
        out = np.zeros((3, 3))
        out[:2, :2] = inv
        out[:2, 2] = -inv @ self.drift_px_per_um
        out[2, 2] = 1.0
        return out

    def to_um(self, q_px: ArrayLike, focus_um: ArrayLike) -> FloatArray:
        """Points in {M}, (N, 3) µm, from images (N, 2) px and focus readings (N,) µm (or a
        single (2,) and a number: (3,))."""
        q = np.asarray(q_px, dtype=np.float64)
        f = np.asarray(focus_um, dtype=np.float64)
        qf = np.column_stack([np.atleast_2d(q), np.atleast_1d(f)])
        qf[:, :2] -= self.centre_px
        out: FloatArray = qf @ self.jacobian().T
        return out[0] if q.ndim == 1 else out

    def cov_to_um(self, cov: FloatArray) -> FloatArray:
        """A covariance (3, 3) of (q_x px, q_y px, f µm) as one in {M}, µm^2."""
        J = self.jacobian()
        out: FloatArray = J @ np.asarray(cov, dtype=np.float64) @ J.T
        return out

    def to_image(self, p_um: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Where points of {M} (N, 3) (or (3,)) are seen: images (N, 2) px and the focus
        readings (N,) µm with them in focus."""
        p = np.atleast_2d(np.asarray(p_um, dtype=np.float64))
        f = p[:, 2]
        q = p[:, :2] @ self.px_per_um.T + np.outer(f, self.drift_px_per_um) + self.centre_px
        if np.ndim(p_um) == 1:
            return q[0], f[:1]
        return q, f
