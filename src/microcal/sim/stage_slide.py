"""A calibration slide on an X-Y stage under a microscope's camera on a focus drive.

The smallest simulator of a one-camera microscope's own calibration (``microcal
scope-calibrate``): a dot-grid slide with hollow marker dots lies on an X-Y stage, a camera
looks down through a telecentric objective (:func:`~microcal.sim.tools.microscope_camera`'s
geometry) and moves with the focus drive. Its truth (:class:`ScopeTruth`) is what the
calibration recovers:

- the pixel size in the object and the camera's rotation about the optical axis against the
  stage's axes;
- the stage's own skew (its y axis off perpendicular to its x axis), so that the
  image-to-stage map is a general affine map, not a similarity;
- radial distortion about the image centre (``k1``, ``k2`` in half image diagonals, as
  :class:`~microcal.geometry.affine_camera.AffineCamera` takes them);
- the focus axis's tilt against the optical axis (the camera moves sideways by
  ``tan(tilt)`` per µm of focus, towards ``focus_azimuth_deg`` in the stage's frame);
- field curvature: the focal surface is a paraboloid about the image centre whose sag at
  the corner is ``field_curvature_um`` (each pixel's blur follows its own defocus).

World frame = the stage's frame at stage position 0: moving the stage to ``s`` moves the
slide by ``W s`` (``W`` the stage's axes, skewed), moving the focus to ``z`` moves the camera
by ``z (tan(tilt) cos(az), tan(tilt) sin(az), 1)``. The slide is in focus at ``z = 0``; away
from it the image blurs by the objective's numerical aperture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray, check_number
from ..errors import InputError
from ..geometry.affine_camera import AffineCamera
from ..vision.targets import Target, parse_target
from .render import Placement, Reflectance
from .slide_render import render_slide

__all__ = [
    "SIM_OBJECTIVES",
    "ScopeTruth",
    "SimObjective",
    "StageSlideScope",
    "random_truth",
    "slide_for",
]


@dataclass(frozen=True)
class SimObjective:
    """A simulated objective: its pixel size in the object on the simulated camera and its NA."""

    um_per_px: float
    numerical_aperture: float


#: The simulated objectives by name (6.5 µm camera pixels).
SIM_OBJECTIVES: dict[str, SimObjective] = {
    "10x": SimObjective(0.65, 0.30),
    "20x": SimObjective(0.325, 0.50),
    "40x": SimObjective(0.1625, 0.80),
}


def slide_for(um_per_px: float) -> str:
    """A marked dot-grid slide whose pitch is about 40 pixels under ``um_per_px``.

    The pitch is rounded to 1, 2 or 5 times a power of ten µm (10 µm at 40x, 20 or 25 µm at
    10x), the dots are half the pitch across, and the three marker dots sit at the slide's
    centre.
    """
    check_number("um_per_px", um_per_px, above=0)
    raw = 40.0 * um_per_px
    decade = 10.0 ** math.floor(math.log10(raw))
    pitch = min((f * decade for f in (1.0, 2.0, 2.5, 5.0, 10.0)), key=lambda p: abs(p - raw))
    return f"dotgrid:41x41:{pitch:g}:{pitch / 2:g}:markers=20,20/22,20/20,19"


@dataclass(frozen=True)
class ScopeTruth:
    """What the simulated microscope is; the calibration recovers it.

    Attributes
    ----------
    um_per_px : float
        Pixel size in the object, µm.
    rotation_deg : float
        The camera's rotation about the optical axis against the stage's x axis, degrees.
    stage_skew_deg : float
        The stage's y axis off perpendicular to its x axis, degrees.
    k1, k2 : float
        Radial distortion about the image centre, in half image diagonals.
    focus_tilt_deg : float
        Angle between the focus axis and the optical axis, degrees.
    focus_azimuth_deg : float
        Direction of that tilt in the stage's x-y plane, degrees from +x.
    numerical_aperture : float
        The objective's NA (the defocus blur).
    slide_rotation_deg : float
        The slide's rotation on the stage, degrees.
    slide_offset_um : (2,) float
        The slide's centre off the field's centre at stage position 0, µm.
    field_curvature_um : float
        The focal surface's sag at the image's corner, µm (a paraboloid about the image
        centre: the corner is in focus when the focus is at this value).
    """

    um_per_px: float = 0.1625
    rotation_deg: float = 0.0
    stage_skew_deg: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    focus_tilt_deg: float = 0.0
    focus_azimuth_deg: float = 0.0
    numerical_aperture: float = 0.8
    slide_rotation_deg: float = 0.0
    slide_offset_um: tuple[float, float] = (0.0, 0.0)
    field_curvature_um: float = 0.0

    def __post_init__(self) -> None:
        check_number("um_per_px", self.um_per_px, above=0)
        if not 0 < self.numerical_aperture < 1.5:
            raise InputError(f"numerical_aperture: expected 0-1.5, got {self.numerical_aperture}")

    def camera_rotation(self) -> FloatArray:
        """Rotation from the world into the camera (looking down, -z), (3, 3)."""
        a = math.radians(self.rotation_deg)
        rz = np.array([[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0],
                       [0.0, 0.0, 1.0]])  # fmt: skip
        out: FloatArray = np.diag([1.0, -1.0, -1.0]) @ rz
        return out

    def stage_axes(self) -> FloatArray:
        """``W``: the world displacement of a stage move by (1, 0) and (0, 1) µm, (2, 2)."""
        s = math.radians(self.stage_skew_deg)
        return np.array([[1.0, math.sin(s)], [0.0, math.cos(s)]])

    def focus_lateral(self) -> FloatArray:
        """The camera's sideways travel per µm of focus, in the world, (2,)."""
        t, az = math.radians(self.focus_tilt_deg), math.radians(self.focus_azimuth_deg)
        return math.tan(t) * np.array([math.cos(az), math.sin(az)])

    def pixels_per_stage(self) -> FloatArray:
        """``M``: the image displacement of the slide's features per stage µm, (2, 2) px/µm."""
        out: FloatArray = (self.camera_rotation()[:2, :2] / self.um_per_px) @ self.stage_axes()
        return out

    def affine_um(self) -> FloatArray:
        """The true image-to-stage affine in Micro-Manager's convention (``docs/conventions.md``),
        (2, 3): ``-M^-1`` and no translation."""
        out: FloatArray = np.zeros((2, 3))
        out[:, :2] = -np.linalg.inv(self.pixels_per_stage())
        return out

    def drift_px_per_um(self) -> FloatArray:
        """The image's drift per µm of focus, (2,) px/µm."""
        out: FloatArray = -(self.camera_rotation()[:2, :2] / self.um_per_px) @ self.focus_lateral()
        return out


def random_truth(seed: int, objective: str = "40x") -> ScopeTruth:
    """A random microscope of one objective (``SIM_OBJECTIVES``): pixel size within 2 %,
    rotation within 3 degrees, stage skew within 0.2 degrees, distortion up to 0.2 % at the
    corner, focus-axis tilt up to 1 degree, the slide turned up to 5 degrees, field curvature
    up to 0.65 µm / NA² at the corner (about the depth of field)."""
    obj = SIM_OBJECTIVES[objective]
    rng = np.random.default_rng(seed)
    return ScopeTruth(
        um_per_px=obj.um_per_px * float(rng.uniform(0.98, 1.02)),
        rotation_deg=float(rng.uniform(-3, 3)),
        stage_skew_deg=float(rng.uniform(-0.2, 0.2)),
        k1=float(rng.uniform(-2e-3, 2e-3)),
        k2=float(rng.uniform(-5e-4, 5e-4)),
        focus_tilt_deg=float(rng.uniform(0.2, 1.0)),
        focus_azimuth_deg=float(rng.uniform(0, 360)),
        numerical_aperture=obj.numerical_aperture,
        slide_rotation_deg=float(rng.uniform(-5, 5)),
        slide_offset_um=(float(rng.normal(0, 2)), float(rng.normal(0, 2))),
        field_curvature_um=float(rng.uniform(-1.0, 1.0)) * 0.65 / obj.numerical_aperture**2,
    )


@dataclass
class StageSlideScope:
    """The simulated microscope: an X-Y stage carrying a slide, a camera on a focus drive.

    Parameters
    ----------
    truth : ScopeTruth
    slide : str
        The slide's target spec (a dot grid with markers; :func:`slide_for` by default).
    image_size_px : (int, int)
        The camera's width and height.
    noise : float
        Standard deviation of the pixels' noise, in reflectance (0-1) units.
    psf_px : float
        Blur of the focused image (the optics' point spread), standard deviation, px.
    stage_sigma_um : float
        Standard deviation of each stage axis's error of position, µm (0: exact).
    seed : int
        Seed of the noise.
    """

    truth: ScopeTruth
    slide: str = ""
    image_size_px: tuple[int, int] = (512, 512)
    noise: float = 0.01
    psf_px: float = 1.0
    stage_sigma_um: float = 0.0
    seed: int = 0
    stage_um: FloatArray = field(default_factory=lambda: np.zeros(2))
    focus_um: float = 0.0
    frames: int = 0
    _rng: np.random.Generator = field(init=False, repr=False)
    _target: Target = field(init=False, repr=False)
    _stage_error_um: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.slide:
            self.slide = slide_for(self.truth.um_per_px)
        self._target = parse_target(self.slide)
        self._rng = np.random.default_rng(self.seed)
        self._stage_error_um = np.zeros(2)

    @property
    def target(self) -> Target:
        """The slide's target."""
        return self._target

    def move_stage(self, xy_um: FloatArray) -> None:
        """Move the X-Y stage to ``xy_um`` (2,), µm (with its error of position, if any)."""
        self.stage_um = np.asarray(xy_um, dtype=np.float64).reshape(2).copy()
        self._stage_error_um = self._rng.normal(0.0, self.stage_sigma_um, 2) \
            if self.stage_sigma_um else np.zeros(2)  # fmt: skip

    def move_focus(self, z_um: float) -> None:
        """Move the focus drive to ``z_um``, µm (0: the slide in focus)."""
        self.focus_um = float(z_um)

    def camera(self) -> AffineCamera:
        """The camera at the current focus (its position moves along the tilted focus axis)."""
        t = self.truth
        w, h = self.image_size_px
        m = 1.0 / t.um_per_px
        K = np.array([[m, 0.0, (w - 1) / 2], [0.0, m, (h - 1) / 2], [0.0, 0.0, 1.0]])
        R = t.camera_rotation()
        lateral = t.focus_lateral() * self.focus_um
        centre = np.array([lateral[0], lateral[1], self.focus_um])
        tvec = -R @ centre + np.array([0.0, 0.0, 1000.0])
        dist = np.array([t.k1, t.k2, 0.0, 0.0, 0.0])
        return AffineCamera(K, dist, R, tvec, (int(w), int(h)), name="scope")

    def placement(self) -> Placement:
        """The slide where the stage has it: its centre at the offset plus the stage's move."""
        t = self.truth
        a = math.radians(t.slide_rotation_deg)
        R = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0],
                      [0.0, 0.0, 1.0]])  # fmt: skip
        moved = t.stage_axes() @ (self.stage_um + self._stage_error_um)
        centre = np.array([*(np.asarray(t.slide_offset_um) + moved), 0.0])
        return Placement(self._target, R, centre - R @ self._target.centre_um, margin_um=0.0)

    def blur_px(self, sag_um: float | FloatArray = 0.0) -> float | FloatArray:
        """Standard deviation of the image's blur at the current focus, px: the optics' own
        and the defocus disc's (radius ``|z - sag| tan(asin(NA))``, taken as two sigmas),
        where the focal surface's sag is ``sag_um`` (a number, or one per pixel)."""
        na = self.truth.numerical_aperture
        disc_um = np.abs(self.focus_um - np.asarray(sag_um)) * math.tan(math.asin(min(na, 0.999)))
        out = np.hypot(self.psf_px, 0.5 * disc_um / self.truth.um_per_px)
        return float(out) if np.ndim(out) == 0 else out

    def sag_um(self) -> FloatArray:
        """The focal surface's sag at each pixel, (h, w) µm."""
        w, h = self.image_size_px
        x = np.arange(w) - (w - 1) / 2
        y = np.arange(h) - (h - 1) / 2
        rho2 = (x[None, :] ** 2 + y[:, None] ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        out: FloatArray = self.truth.field_curvature_um * rho2
        return out

    def _blurred(self, img: NDArray[np.float32]) -> NDArray[np.float32]:
        """The image blurred as each pixel's defocus says (levels of blur blended per pixel)."""
        if self.truth.field_curvature_um == 0:
            flat: NDArray[np.float32] = cv2.GaussianBlur(img, (0, 0), float(self.blur_px()))
            return flat
        sigma = np.asarray(self.blur_px(self.sag_um()), dtype=np.float64)
        levels = np.linspace(sigma.min(), sigma.max(), 6)
        stack = np.stack([cv2.GaussianBlur(img, (0, 0), float(s)) for s in levels])
        pos = np.clip((sigma - levels[0]) / max(levels[1] - levels[0], 1e-12), 0, len(levels) - 1)
        lo = np.minimum(np.floor(pos).astype(int), len(levels) - 2)
        f = (pos - lo).astype(np.float32)
        rows, cols = np.indices(sigma.shape)
        out: NDArray[np.float32] = (1 - f) * stack[lo, rows, cols] + f * stack[lo + 1, rows, cols]
        return out

    def grab(self) -> NDArray[np.float32]:
        """One frame, (h, w) float32 in reflectance units, with blur and noise."""
        w, h = self.image_size_px
        refl = Reflectance()
        value, alpha = render_slide(self.camera(), self.placement(), (0, 0, w, h),
                                    supersample=3, reflectance=refl)  # fmt: skip
        img = (refl.glass + alpha * (np.nan_to_num(value) - refl.glass)).astype(np.float32)
        out = self._blurred(img)
        out += self._rng.normal(0.0, self.noise, out.shape).astype(np.float32)
        self.frames += 1
        return out
