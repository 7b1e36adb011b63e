"""The camera-model protocol: what measurement and triangulation ask of a calibrated camera.

A camera model maps points of the world frame {G} (µm) to pixels of its image. microcal's
procedures use a camera only through the members listed in :class:`CameraModelProtocol`, so
a new kind of camera (an affine, telecentric one, say) implements these members and is then
measured and triangulated like the pinhole :class:`~microcal.geometry.camera_model.CameraModel`.

The contract every camera model keeps (``tests/geometry/test_camera_protocol.py`` checks it
for each kind):

- ``project`` includes the lens distortion; ``undistort_px`` removes it, giving the pixels of
  the ideal camera whose linear projection matrix is ``P``:
  ``undistort_px(project(p)) == project_points(P, p)``.
- ``project_jacobian`` is the derivative of ``project`` with respect to the world point.
- ``back_project(project(p))`` is a ray through ``p``.
- ``P`` is a 3x4 matrix in one of two forms, told apart by its third row:
  ``P[2, :3] != 0`` for a camera with a projection centre (pinhole, ``kind == "pinhole"``),
  ``P[2, :3] == 0`` for an affine camera (parallel projection). Triangulation accepts both
  (see :func:`~microcal.geometry.projection_matrix.normalize_camera_matrix`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..errors import InputError

__all__ = ["PROTOCOL_MEMBERS", "CameraModelProtocol", "check_camera_model"]


@runtime_checkable
class CameraModelProtocol(Protocol):
    """A calibrated camera, as measurement and triangulation use it.

    Attributes
    ----------
    name : str
        Free name of the camera ("top", "side" ...).
    image_size_px : (int, int)
        Image width and height in pixels.
    kind : str
        The model's kind, as cameras.json's ``"model"`` key spells it (``"pinhole"``).
    P : (3, 4) float
        Linear projection matrix of the undistorted image (world in µm): the pixels
        :meth:`undistort_px` returns are ``P [p; 1]`` dehomogenised. ``P[2, :3] = 0`` for an
        affine camera.
    """

    @property
    def name(self) -> str:
        """Free name of the camera."""
        ...

    @property
    def image_size_px(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        ...

    @property
    def kind(self) -> str:
        """The model's kind: ``"pinhole"``, or the name a new kind registers."""
        ...

    @property
    def P(self) -> FloatArray:
        """(3, 4) linear projection matrix of the undistorted image, world in µm."""
        ...

    def project(self, p_um: ArrayLike) -> FloatArray:
        """Project world points into the image, lens distortion included.

        Parameters
        ----------
        p_um : (N, 3) or (3,) float
            Points in {G}, µm.

        Returns
        -------
        q_px : (N, 2) float
            Pixel coordinates (x, y); NaN for points the camera cannot see.
        """
        ...

    def project_jacobian(self, p_um: ArrayLike) -> FloatArray:
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
        ...

    def undistort_px(self, q_px: ArrayLike) -> FloatArray:
        """Remove the lens distortion from observed pixels.

        Parameters
        ----------
        q_px : (N, 2) or (2,) float
            Observed pixel coordinates.

        Returns
        -------
        q_ideal_px : (N, 2) float
            Pixels of the ideal camera ``P``; NaN where the inversion failed.
        """
        ...

    def back_project(self, q_px: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """The rays of {G} that observed pixels come from.

        Parameters
        ----------
        q_px : (N, 2) or (2,) float
            Observed pixel coordinates (lens distortion included).

        Returns
        -------
        origin_um : (N, 3) float
            A point of each ray in {G}, µm.
        direction : (N, 3) float
            Unit direction of each ray in {G}, pointing away from the camera into the scene.
        """
        ...


#: The members a camera model must have, in the order the protocol lists them.
PROTOCOL_MEMBERS = (
    "name",
    "image_size_px",
    "kind",
    "P",
    "project",
    "project_jacobian",
    "undistort_px",
    "back_project",
)


def check_camera_model(camera: object, name: str = "camera") -> CameraModelProtocol:
    """Check that an object implements :class:`CameraModelProtocol`.

    Parameters
    ----------
    camera : object
        The candidate.
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    camera : CameraModelProtocol
        The same object.

    Raises
    ------
    InputError
        If a member is missing: ``camera1: expected a camera model (members name, ...),
        got dict without P, project, ...``.
    """
    if isinstance(camera, CameraModelProtocol):
        return camera
    missing = [m for m in PROTOCOL_MEMBERS if not hasattr(camera, m)]
    raise InputError(
        f"{name}: expected a camera model (members {', '.join(PROTOCOL_MEMBERS)}), got "
        f"{type(camera).__name__} without {', '.join(missing)}"
    )
