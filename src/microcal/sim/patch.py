"""The simulator's ``patch`` preset: one camera on an upright microscope, as patch-clamp and
injection rigs have.

- **The camera** looks down through a water-immersion objective (40x, NA 0.8 by default)
  onto a sensor of 2048 x 2048 pixels of 6.5 µm: 0.1625 µm per pixel in the object, a field
  of 333 µm. The view is telecentric (an objective's object space nearly is) and free of
  distortion (:func:`~microcal.sim.tools.microscope_camera`).
- **Defocus** follows the numerical aperture (:class:`~microcal.sim.tools.Optics`):
  diffraction in focus, the circle of confusion off it; the depth of field,
  ``lambda n / NA^2 + n e / NA``, is 1.41 µm.
- **The focus drive** (:class:`~microcal.sim.focus_drive.FocusDrive`) moves the objective in
  z with its own errors: scale, tilt of the focus axis against the optical axis, backlash,
  scatter. {G} is the microscope's frame: x, y in the focal plane of the focus's home
  (the image's x right, y down seen from above: {G}'s +x and -y), z up.
- **The X-Y stage** (:class:`~microcal.sim.stage.SimStage`, z held) moves the sample: a
  tissue-like bright-field texture that changes with the focus (other cells come into
  focus every few microns); the manipulator and the microscope stay put.
- **The manipulator** (:class:`~microcal.sim.manipulator.SimManipulator`) carries a glass
  pipette; its x axis is the approach axis, tilted :data:`APPROACH_DEG` below horizontal
  (along the pipette), its y axis horizontal and its z axis vertical, each with small
  errors of the size the thesis's manipulator has. Joints at the middle of their travel
  put the tip at {G}'s origin.

Frames are lazy (:class:`PatchFrame`, a :class:`~microcal.vision.lazy_frame.RegionFrame`):
a region is rendered when it is read, so a procedure that looks at the tip's neighbourhood
pays for a few hundred pixels squared, not for 4 megapixels. Each frame's noise is drawn
per 64 x 64 tile from the frame's own seed, the sample is a function of position and the
tool's blur is computed for the whole frame but only where it is read
(:class:`~microcal.sim.tool_layer.ToolLayer`), so a pixel has the same value whichever
region it is read in (within float32 rounding), and a whole frame takes a few seconds.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray, check_number
from ..devices.base import Clock
from ..geometry.affine_camera import AffineCamera
from ..kinematics.models import KinematicModel
from ..kinematics.terms import JOINTS, polynomial_terms
from .clock import SimClock
from .focus_drive import FocusDrive, FocusErrors
from .kinematics import TrueKinematics
from .manipulator import SimManipulator
from .stage import SimStage
from .tool_layer import ToolLayer
from .tools import Background, Optics, Tool, ToolPlacement, microscope_camera
from .tools import tool_axis as _tool_axis

__all__ = [
    "APPROACH_DEG",
    "PATCH_PRESET",
    "PatchConfig",
    "PatchFrame",
    "PatchRig",
    "PatchTruth",
    "patch_kinematics",
    "patch_rig",
]

#: The preset's name.
PATCH_PRESET = "patch"
#: The manipulator's approach axis below horizontal, degrees (patch rigs: 20-40).
APPROACH_DEG = 30.0
#: Where the focal plane lies in the camera model's depth (microscope_camera's 1 mm).
_FOCAL_DEPTH_UM = 1000.0
#: Side of the tiles the noise is drawn in, px.
_TILE = 64
#: Size of a texel of the sample's texture, in camera pixels (4: 0.65 µm at 40x).
_TEXEL_PX = 4
#: Texels of the (periodic) texture per side.
_TEXELS = 1024

Box = tuple[int, int, int, int]


@dataclass(frozen=True)
class PatchConfig:
    """Every parameter of the ``patch`` preset.

    Attributes
    ----------
    magnification, numerical_aperture, refractive_index, wavelength_um : float
        The objective (40x / NA 0.8 water by default) and the light.
    sensor_pixel_um : float
        The camera's pixel, µm on the sensor.
    size_px : (int, int)
        Width and height of a frame, px.
    approach_deg, approach_azimuth_deg : float
        The manipulator's approach axis: below horizontal, and the direction in {G}'s x-y
        plane its shank points to (from +x towards +y), degrees.
    tool : Tool
        What the manipulator carries (a pipette of 10 degrees with a 1 µm opening).
    focus : FocusErrors
    tissue_contrast : float
        Depth of the sample's texture (0: clear medium).
    focus_period_um : float
        How far the focus moves before the texture shows other cells, µm.
    light_level, light_gradient : float, (float, float)
        The clear field's light (fraction of full scale) and its change across the field.
    full_well_e, read_noise_e : float
    bit_depth : int
    exposure_s, readout_s : float
    supersample : int
        S x S subsamples per pixel for the tool's outline.
    """

    magnification: float = 40.0
    numerical_aperture: float = 0.8
    refractive_index: float = 1.333
    wavelength_um: float = 0.55
    sensor_pixel_um: float = 6.5
    size_px: tuple[int, int] = (2048, 2048)
    approach_deg: float = APPROACH_DEG
    approach_azimuth_deg: float = 0.0
    tool: Tool = field(default_factory=lambda: Tool("pipette", taper_deg=10.0, tip_um=1.0))
    focus: FocusErrors = field(default_factory=FocusErrors)
    tissue_contrast: float = 0.12
    focus_period_um: float = 6.0
    light_level: float = 0.7
    light_gradient: tuple[float, float] = (0.08, -0.05)
    full_well_e: float = 15000.0
    read_noise_e: float = 2.0
    bit_depth: int = 12
    exposure_s: float = 0.02
    readout_s: float = 0.01
    supersample: int = 3

    def __post_init__(self) -> None:
        check_number("magnification", self.magnification, above=0)
        check_number("sensor_pixel_um", self.sensor_pixel_um, above=0)
        check_number("approach_deg", self.approach_deg, low=0, high=89)
        check_number("tissue_contrast", self.tissue_contrast, low=0, high=0.5)
        check_number("focus_period_um", self.focus_period_um, above=0)
        check_number("supersample", self.supersample, low=1, high=8, integer=True)
        Optics(self.numerical_aperture, self.wavelength_um, 0.0, self.refractive_index)

    @property
    def um_per_px(self) -> float:
        """The pixel's size in the object, µm."""
        return self.sensor_pixel_um / self.magnification

    @property
    def field_um(self) -> tuple[float, float]:
        """The field of view's width and height, µm."""
        return self.size_px[0] * self.um_per_px, self.size_px[1] * self.um_per_px

    @property
    def optics(self) -> Optics:
        """The objective, focused at the camera model's focal depth."""
        return Optics(self.numerical_aperture, self.wavelength_um, _FOCAL_DEPTH_UM,
                      self.refractive_index)  # fmt: skip

    @property
    def depth_of_field_um(self) -> float:
        """The objective's depth of field on this camera, µm."""
        return self.optics.depth_of_field_um(self.um_per_px)

    @property
    def tool_axis(self) -> FloatArray:
        """Unit direction from the tip towards the shank in {G}, (3,)."""
        return _tool_axis(self.approach_deg, self.approach_azimuth_deg)


def patch_kinematics(config: PatchConfig, centre_um: float = 10000.0) -> TrueKinematics:
    """The patch manipulator's true kinematics: x along the approach axis (forward: into the
    sample, along the pipette), y horizontal across it, z vertical, each with small
    couplings; joints at ``centre_um`` put the tip at {G}'s origin."""
    forward = -config.tool_axis
    across = np.cross(np.array([0.0, 0.0, 1.0]), forward)
    across /= np.linalg.norm(across)
    axes = np.column_stack([forward, across, [0.0, 0.0, 1.0]])
    errors = np.array([[1.0004, -0.0008, 0.0003], [0.0006, 0.9997, -0.0012],
                       [-0.0005, 0.0010, 1.0006]])  # fmt: skip
    linear = axes @ errors
    terms = polynomial_terms(JOINTS, 2)
    names = [t.name for t in terms]
    coef = np.zeros((3, len(terms)))
    for j, joint in enumerate(JOINTS):
        coef[:, names.index(joint)] = linear[:, j]
    coef[2, names.index("dx^2")] = -2e-7  # the approach axis sags a little
    coef[:, names.index("1")] = -linear @ np.full(3, centre_um) + 2e-7 * centre_um**2 * np.eye(3)[2]
    static = KinematicModel(
        kind="polynomial", inputs=JOINTS, joints=JOINTS, terms=terms, coefficients=coef,
        selected=coef != 0, covariance=np.zeros((3, len(terms), len(terms))),
        selection={"method": "truth"},
    )  # fmt: skip
    return TrueKinematics(
        static=static, hysteresis_um=np.array([0.3, 0.2, 0.3]),
        thermal_um_per_c=np.array([0.4, -0.3, 0.6]), creep_fraction=5e-4, creep_tau_s=0.5,
    )  # fmt: skip


@dataclass
class PatchTruth:
    """Where the tip is in a frame (ground truth for tests and figures).

    Attributes
    ----------
    tip_um : (3,) float
        The tip point in {G}, µm.
    tip_px : (2,) float
        Its image, px.
    objective_um : (3,) float
        The objective's true offset from its home, µm ({G}).
    focus_command_um : float
        The focus drive's readout.
    defocus_um : float
        The tip's height above the focal plane, µm (positive: the focus is below the tip).
    """

    tip_um: FloatArray
    tip_px: FloatArray
    objective_um: FloatArray
    focus_command_um: float
    defocus_um: float


class PatchFrame:
    """One frame of the ``patch`` camera, rendered where it is read (a
    :class:`~microcal.vision.lazy_frame.RegionFrame`), with its truth."""

    def __init__(
        self,
        rig: PatchRig,
        camera: AffineCamera,
        placement: ToolPlacement,
        focus_um: float,
        stage_um: FloatArray,
        seed: tuple[int, ...],
        truth: PatchTruth,
    ) -> None:
        self._rig = rig
        self.camera = camera
        self._placement = placement
        self._focus_um = focus_um
        self._stage_um = stage_um
        self._seed = seed
        self.truth = truth
        self._full: NDArray[np.uint16] | None = None
        self._tool: ToolLayer | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the whole frame, px."""
        w, h = self.camera.image_size_px
        return int(h), int(w)

    def region(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.uint16]:
        """The frame's pixels over [x0, x1) x [y0, y1) (clipped to the frame), a new array."""
        h, w = self.shape
        x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
        if self._full is not None:
            return self._full[y0:y1, x0:x1].copy()
        if x1 <= x0 or y1 <= y0:
            return np.zeros((max(y1 - y0, 0), max(x1 - x0, 0)), dtype=np.uint16)
        cfg = self._rig.config
        box = (x0, y0, x1, y1)
        light = self._rig.sample_light(box, self._stage_um, self._focus_um, self.camera)
        if self._tool is None:
            self._tool = ToolLayer(self.camera, self._placement, cfg.optics, cfg.supersample)
        light *= self._tool.transmission(box)
        return self._expose(light, box)

    def full(self) -> NDArray[np.uint16]:
        """The whole frame (about 3 s to render at 2048 x 2048; made once)."""
        if self._full is None:
            h, w = self.shape
            self._full = self.region(0, 0, w, h)
        return self._full

    def _expose(self, light: NDArray[np.float32], box: Box) -> NDArray[np.uint16]:
        cfg = self._rig.config
        x0, y0, x1, y1 = box
        noise = np.empty(light.shape, dtype=np.float32)
        for ty in range(y0 // _TILE, (y1 - 1) // _TILE + 1):
            for tx in range(x0 // _TILE, (x1 - 1) // _TILE + 1):
                rng = np.random.default_rng([*self._seed, tx, ty])
                tile = rng.standard_normal((_TILE, _TILE), dtype=np.float32)
                ax0, ay0 = max(x0, tx * _TILE), max(y0, ty * _TILE)
                ax1, ay1 = min(x1, (tx + 1) * _TILE), min(y1, (ty + 1) * _TILE)
                noise[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0] = tile[
                    ay0 - ty * _TILE : ay1 - ty * _TILE, ax0 - tx * _TILE : ax1 - tx * _TILE
                ]
        top = 2**cfg.bit_depth - 1
        electrons = np.clip(light, 0.0, None) * np.float32(cfg.full_well_e)
        noisy = electrons + noise * np.sqrt(electrons + np.float32(cfg.read_noise_e**2))
        dn = np.clip(np.rint(noisy * np.float32(top / cfg.full_well_e)), 0, top)
        out: NDArray[np.uint16] = dn.astype(np.uint16)
        return out


class PatchRig:
    """The ``patch`` preset's devices and truth (see the module docstring).

    Attributes
    ----------
    config : PatchConfig
    clock : Clock
    focus : FocusDrive
    stage : SimStage
        The X-Y stage under the sample (z held at 0).
    manipulator : SimManipulator
        The pipette's manipulator (``m1``).

    ``clock`` is the rig's clock (a :class:`SimClock` of its own by default; the digital
    twin gives its scaled clock).
    """

    def __init__(self, config: PatchConfig, seed: int = 0, clock: Clock | None = None) -> None:
        self.config = config
        self.seed = int(seed)
        root = np.random.SeedSequence([self.seed, 35])
        s_focus, s_stage, s_manip, s_tex = root.spawn(4)
        self.clock: Clock = SimClock() if clock is None else clock
        self.focus = FocusDrive(self.clock, np.random.default_rng(s_focus), config.focus)
        xy_limits = ((-5000.0, 5000.0), (-5000.0, 5000.0), (0.0, 0.0))
        self.stage = SimStage(self.clock, np.random.default_rng(s_stage), name="xy",
                              limits_um=xy_limits)  # fmt: skip
        self.manipulator = SimManipulator(
            patch_kinematics(config), self.clock, np.random.default_rng(s_manip),
            limits_um=((0.0, 20000.0),) * 3, speed_um_s=1000.0, loop_settle_s=0.2,
            sensor_noise_um=0.02,
        )  # fmt: skip
        self.manipulator.move_to_um(np.full(3, 10000.0))  # the tip at {G}'s origin
        self.clock.sleep(20.0)
        tex_seed = int(s_tex.generate_state(1)[0])
        self._texture = [
            _relative_texture(Background("tissue", 0.5, level=0.5, seed=tex_seed + i))
            for i in range(2)
        ]
        self._n_frames = 0

    # -- truth -----------------------------------------------------------------------------
    def placement(self) -> ToolPlacement:
        """The tool where the manipulator truly holds it now."""
        return ToolPlacement(self.config.tool, self.manipulator.true_position_um(),
                             self.config.tool_axis)  # fmt: skip

    def camera(self) -> AffineCamera:
        """The camera model with the objective where it truly is now (ground truth)."""
        cfg = self.config
        centre = self.focus.objective_offset_um()
        return microscope_camera(cfg.um_per_px, cfg.size_px, centre_um=centre, name="scope")

    def truth(self) -> PatchTruth:
        """Where the tip is now and how far from focus."""
        cam, tip = self.camera(), self.manipulator.true_position_um()
        obj = self.focus.objective_offset_um()
        return PatchTruth(tip, cam.project(tip[None, :])[0], obj, self.focus.position_um(),
                          float(tip[2] - obj[2]))  # fmt: skip

    def in_focus(self) -> tuple[float, FloatArray]:
        """The focus reading that puts the tip in focus, and the tip's image there, (2,) px
        (ground truth; the focus drive is left where it was)."""
        tip = self.manipulator.true_position_um()
        e = self.config.focus
        reading = float(tip[2] / ((1.0 + e.scale) * e.axis[2]))
        here = self.focus.position_um()
        self.move_focus(reading)
        px: FloatArray = self.camera().project(tip[None, :])[0]
        self.move_focus(here)
        return reading, px

    # -- devices ---------------------------------------------------------------------------
    def grab(self) -> PatchFrame:
        """A frame now (lazy): the exposure and readout pass on the rig's clock."""
        self._n_frames += 1
        seq = (self.seed, 35, 7, self._n_frames)
        frame = PatchFrame(self, self.camera(), self.placement(), self.focus.position_um(),
                           self.stage.joints_um(self.clock.now_s())[:2].copy(), seq,
                           self.truth())  # fmt: skip
        self.clock.sleep(self.config.exposure_s + self.config.readout_s)
        return frame

    def move_focus(self, z_um: float) -> None:
        """Move the focus to ``z_um``, approaching from below (a move down first overshoots
        by twice the backlash), as a focus drive's backlash compensation does."""
        if z_um < self.focus.position_um():
            below = max(z_um - 2.0 * self.config.focus.backlash_um - 0.5, self.focus.limits_um[0])
            self.focus.move_to(below)
        self.focus.move_to(z_um)

    def grab_at_focus(self, z_um: float) -> PatchFrame:
        """Move the focus to ``z_um`` (from below) and grab a frame."""
        self.move_focus(z_um)
        return self.grab()

    def frames_grabbed(self) -> int:
        """Frames grabbed so far."""
        return self._n_frames

    # -- the sample ------------------------------------------------------------------------
    def sample_light(
        self, box: Box, stage_um: FloatArray, focus_um: float, camera: AffineCamera
    ) -> NDArray[np.float32]:
        """The bright field's light over ``box`` (h, w) float32: the uneven illumination
        times the sample's texture, moved with the stage, changing with the focus."""
        cfg = self.config
        x0, y0, x1, y1 = box
        W, H = cfg.size_px
        xs = np.arange(x0, x1, dtype=np.float32)
        ys = np.arange(y0, y1, dtype=np.float32)
        gx, gy = cfg.light_gradient
        light = cfg.light_level * (1.0 + gx * (xs[None, :] / (W - 1) - 0.5)
                                   + gy * (ys[:, None] / (H - 1) - 0.5))  # fmt: skip
        if cfg.tissue_contrast > 0:
            # sample point under each pixel: the field's centre follows the objective, the
            # sample the stage; texels of _TEXEL_PX pixels
            cx, cy = float(camera.K[0, 2]), float(camera.K[1, 2])
            ox, oy = (camera.project(np.zeros((1, 3)))[0] - (cx, cy)).tolist()
            shift_x = -ox - stage_um[0] / cfg.um_per_px
            shift_y = -oy + stage_um[1] / cfg.um_per_px
            map_x = np.broadcast_to((xs[None, :] + shift_x) / _TEXEL_PX, light.shape)
            map_y = np.broadcast_to((ys[:, None] + shift_y) / _TEXEL_PX, light.shape)
            mx, my = (
                np.ascontiguousarray(map_x, np.float32),
                np.ascontiguousarray(map_y, np.float32),
            )
            a = cv2.remap(self._texture[0], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            b = cv2.remap(self._texture[1], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            phase = math.pi / 2.0 * focus_um / cfg.focus_period_um
            tex = math.cos(phase) * a + math.sin(phase) * b
            light = light * (1.0 + cfg.tissue_contrast * tex)
        out: NDArray[np.float32] = np.clip(light, 0.0, 1.0).astype(np.float32)
        return out


def _relative_texture(background: Background) -> NDArray[np.float32]:
    """A tissue texture of unit spread around 0, (_TEXELS, _TEXELS) float32."""
    img = background.image((_TEXELS, _TEXELS)) / np.float32(background.level) - 1.0
    out: NDArray[np.float32] = (img / max(float(img.std()), 1e-9)).astype(np.float32)
    return out


def patch_rig(seed: int = 0, **changes: object) -> PatchRig:
    """The ``patch`` preset's rig for ``seed``; ``changes`` replace :class:`PatchConfig`
    fields (``approach_deg=25``, ``size_px=(256, 256)``), each checked."""
    config = dataclasses.replace(PatchConfig(), **changes)  # type: ignore[arg-type]
    return PatchRig(config, seed)
