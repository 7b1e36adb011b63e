"""The kinds of camera model microcal implements, by cameras.json's ``"model"`` name.

Procedures use a camera through :class:`~.camera_protocol.CameraModelProtocol`; the simulator
and the calibration also need each kind's own parameters (K, R, t, distortion), which both
kinds below have with the same names and meanings for R and t.
"""

from __future__ import annotations

from .affine_camera import AffineCamera
from .camera_model import CameraModel

__all__ = ["CAMERA_KINDS", "AnyCamera"]

#: A calibrated camera of one of microcal's kinds.
AnyCamera = CameraModel | AffineCamera

#: cameras.json's ``"model"`` -> the class.
CAMERA_KINDS: dict[str, type[CameraModel] | type[AffineCamera]] = {
    "pinhole": CameraModel,
    "affine": AffineCamera,
}
