"""The whole simulated platform: manipulator, cameras, clock, scene and ground truth.

``microcal.sim.platform(preset="thesis", seed=0)`` builds the thesis's platform (section 2.4
and 5.1): a top camera of 1600 x 1200 px with the thesis's P, a side camera of 2452 x 2056 px
binned 2 x 2 with the thesis's P', both with a plausible lens distortion; a three-axis
stick-slip manipulator with the true kinematics of
:func:`~microcal.sim.thesis_kinematics.thesis_kinematics`; the 4 x 3
chessboard (pitch 400 µm) on the gripper, its inner-corner centroid being the end-effector.

The other presets (:data:`PRESETS`) change the cameras only, but for ``population``:

- ``telecentric``: both cameras object-side telecentric (affine, parallel projection), each
  with the magnification the thesis's camera has at the middle of the travel, the same pose,
  image size, noise and depth of field, and a distortion of the size telecentric lenses are
  sold with (0.1 % of the field radius at the corner).
- ``thesis-3cam``: the thesis's two cameras and a third, ``front``, the side camera's twin
  (sensor, lens, distance from the travel's middle) tilted 35 degrees off its axis towards
  +y, mirroring the top camera (tilted as much towards -y): a second baseline across the
  side camera's axis, so that depth (z) is seen twice and no longer dominates the error.
- ``population``: every seed another platform: its true kinematics (with errors outside the
  polynomial family), its room's temperature cycle and its cameras' placement and
  magnification drawn by :func:`~microcal.sim.population.draw_population`, its motion noise
  and reversal error with memory drawn with them.
- ``thesis-real``: the ``thesis`` platform with motion noise and reversal error with memory
  (:data:`THESIS_PLAY`, :data:`THESIS_MOTION`, :mod:`~microcal.sim.motion`); everything
  else, frames included, as ``thesis``.
- ``thesis-tip``: the ``thesis`` platform with a glass pipette on the manipulator instead of
  the board (:data:`THESIS_TIP`, markerless): its tip point at the end-effector, its shank
  along {G}'s +x rising :data:`TOOL_ELEVATION_DEG` towards +z, seen against a bright field
  (:mod:`~microcal.sim.tools`, :mod:`~microcal.sim.tool_render`).
- ``thesis-gripper``: the ``thesis`` platform whose end-effector carries a gripper jaw
  beside its board (:mod:`~microcal.sim.carried_tool`): both are seen, the jaw's tip at a
  fixed offset in the board's frame (``tool_offset_um``), for the tool-centre point.

Any preset takes a tool's tip instead of the board when its ``board`` is a tip spec
(``tip:needle``, :mod:`~microcal.vision.tip_target`).

A rig file turns these effects on or off on any preset with ``manipulator.real_motion``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._validation import FloatArray, check_number, did_you_mean
from ..devices.base import Clock
from ..errors import InputError
from ..geometry.affine_camera import AffineCamera
from ..geometry.camera_kinds import CAMERA_KINDS, AnyCamera
from ..geometry.camera_model import DIST_LENGTHS, CameraModel
from ..thesis.cameras import thesis_cameras
from ..vision.targets import Target, parse_spec, parse_target
from ..vision.tip_target import TipTarget
from .camera import CameraFaults, ImageFormation, SimCamera
from .carried_tool import CarriedTool, carried_tool
from .clock import SimClock
from .manipulator import ManipulatorFaults, SimManipulator
from .motion import MotionNoise, PlayHysteresis, play_radii_um
from .population import PopulationDraw, draw_population
from .render import Placement, Reflectance
from .stage import SimStage
from .tools import Tool, ToolPlacement, tool_axis

__all__ = ["PlatformConfig", "Scene", "SimPlatform", "check_overrides", "platform"]


@dataclass
class CameraConfig:
    """One simulated camera."""

    dist: tuple[float, ...]
    pixel_size_um: float
    bit_depth: int = 8
    formation: ImageFormation = field(default_factory=ImageFormation)
    faults: CameraFaults = field(default_factory=CameraFaults)
    projection: str = "pinhole"
    """``"pinhole"`` (perspective, dist on normalised coordinates) or ``"affine"``
    (telecentric, dist in units of half the image diagonal; see
    :class:`~microcal.geometry.affine_camera.AffineCamera`)."""

    def __post_init__(self) -> None:
        if self.projection not in CAMERA_KINDS:
            raise InputError(
                f"projection: expected one of {', '.join(CAMERA_KINDS)}, got {self.projection!r}"
            )
        if len(self.dist) not in DIST_LENGTHS:
            raise InputError(
                f"dist: expected {', '.join(map(str, DIST_LENGTHS))} coefficients, got "
                f"{len(self.dist)}"
            )
        for v in self.dist:
            check_number("dist", v, low=-10, high=10)
        check_number("pixel_size_um", self.pixel_size_um, above=0)
        if self.bit_depth not in (8, 10, 12, 16) or isinstance(self.bit_depth, bool):
            raise InputError(f"bit_depth: expected 8, 10, 12 or 16, got {self.bit_depth!r}")


@dataclass
class ManipulatorConfig:
    """The simulated manipulator (see :class:`SimManipulator`)."""

    # The positioner's travel: the thesis's test range (x, y 0-8000, z 0-4800 µm) with 0.5 mm
    # to spare on every side, so a compensated move at the edge of that range stays inside.
    limits_um: tuple[tuple[float, float], ...] = (
        (-500.0, 8500.0),
        (-500.0, 8500.0),
        (-500.0, 5300.0),
    )
    speed_um_s: float = 2000.0
    loop_settle_s: float = 0.4
    sensor_noise_um: float = 0.05
    temperature_c: float = 22.0
    temperature_drift_c_per_h: float = 0.0
    faults: ManipulatorFaults = field(default_factory=ManipulatorFaults)
    #: A change since the calibration (for ``microcal check``): the end-effector shifted in
    #: {G} (a re-mounted device, an exchanged tool), µm, and each joint's scale.
    mount_offset_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    joint_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    #: Motion noise (step quantisation, scatter) and reversal error with memory (play
    #: operators): the preset's sizes (:data:`THESIS_PLAY`, :data:`THESIS_MOTION`, or the
    #: population's draw) when on; the ideal motion of the ``thesis`` preset when off.
    real_motion: bool = False

    def __post_init__(self) -> None:
        lim = np.asarray(self.limits_um, dtype=np.float64) if _rows_of_two(self.limits_um) else None
        if (
            lim is None
            or lim.shape != (3, 2)
            or not np.all(np.isfinite(lim))
            or np.any(lim[:, 0] > lim[:, 1])
            or np.all(lim[:, 0] == lim[:, 1])
        ):
            raise InputError(
                f"limits_um: expected [low, high] µm for x, y and z (low == high for an axis "
                f"the device lacks), got {self.limits_um!r}"
            )
        check_number("speed_um_s", self.speed_um_s, above=0)
        check_number("loop_settle_s", self.loop_settle_s, low=0)
        check_number("sensor_noise_um", self.sensor_noise_um, low=0)
        check_number("temperature_c", self.temperature_c, low=-50, high=100)
        check_number("temperature_drift_c_per_h", self.temperature_drift_c_per_h, low=-20, high=20)
        for name, value, low, high in (("mount_offset_um", self.mount_offset_um, -1e4, 1e4),
                                       ("joint_scale", self.joint_scale, 0.5, 2.0)):  # fmt: skip
            v = np.asarray(value, dtype=np.float64) if _numbers(value) else None
            if v is None or v.shape != (3,) or not np.all((v >= low) & (v <= high)):
                raise InputError(
                    f"{name}: expected three numbers in [{low:g}, {high:g}], got {value!r}"
                )


def _numbers(value: object) -> bool:
    return isinstance(value, list | tuple) and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in value
    )


def _rows_of_two(value: object) -> bool:
    return isinstance(value, tuple | list) and all(
        isinstance(r, tuple | list) and len(r) == 2 and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in r
        ) for r in value
    )  # fmt: skip


#: The camera-calibration target on the target stage: a dot grid, 40 x 30 dots at 250 µm.
CALIBRATION_TARGET = "dotgrid:40x30:250"
#: A calibration slide that overfills the field, numbered from hollow marker dots near its
#: middle: an option of the ``thesis`` and ``telecentric`` presets, chosen by overriding
#: ``calibration_target`` with it.
OVERFILLING_SLIDE = "dotgrid:60x45:500:300:markers=28,23/33,23/28,20"
#: An end-effector target numbered from hollow marker dots near its middle, measured from
#: whatever part of it is in view: an option of every preset, chosen by overriding ``board``.
MARKED_END_EFFECTOR = "dotgrid:14x10:500:300:markers=5,6/10,6/5,3"


@dataclass
class PlatformConfig:
    """Every parameter of a simulated platform."""

    board: str = "chessboard:4x3:400"
    """The end-effector's target: a board's spec, or a tool's tip (``tip:pipette:10:1``)."""
    tool_elevation_deg: float = 20.0
    """A tool's shank (``board`` a tip spec): its angle above {G}'s x-y plane, degrees."""
    tool_azimuth_deg: float = 0.0
    """A tool's shank: its direction in {G}'s x-y plane from +x towards +y, degrees."""
    tool: str = ""
    """A tool carried beside the board (a tip spec, ``tip:jaw:30:40``; the preset
    ``thesis-gripper``), its shank along ``tool_elevation_deg`` / ``tool_azimuth_deg``;
    empty: none (:mod:`~microcal.sim.carried_tool`)."""
    tool_offset_um: tuple[float, float, float] = (-2400.0, 0.0, 0.0)
    """The carried tool's tip point in the board's frame, µm (the tool-centre point's truth)."""
    calibration_target: str = CALIBRATION_TARGET
    """The target on the target stage (method (a) of the stereo calibration)."""
    top: CameraConfig = field(
        default_factory=lambda: CameraConfig(
            dist=(0.5, 0.0, 1e-3, -1e-3, 0.0),
            pixel_size_um=4.4,
            formation=ImageFormation(jitter_px=(0.05, 0.0)),
        )
    )
    side: CameraConfig = field(
        default_factory=lambda: CameraConfig(
            dist=(0.4, 0.0, -1e-3, 1e-3, 0.0),
            pixel_size_um=6.9,
            formation=ImageFormation(jitter_px=(0.05, 0.0)),
        )
    )
    manipulator: ManipulatorConfig = field(default_factory=ManipulatorConfig)
    front: CameraConfig | None = None
    """A third camera (preset ``thesis-3cam``); None: none."""
    m2: ManipulatorConfig | None = None
    """A second manipulator (preset ``thesis-platform``); None: none."""
    p1: ManipulatorConfig | None = None
    """The sample's positioner (preset ``thesis-platform``); None: none."""


#: The one-camera microscope's preset (``microcal.sim.patch.patch_rig``): a rig of its own
#: kind, not one of :data:`PRESETS`; a rig file's ``preset = "patch"`` opens it as a ``Rig``
#: (``microcal.sim.patch_devices.patch_as_rig``), ``microcal demo --preset patch`` runs it.
ONE_CAMERA_PRESET = "patch"

#: The simulator's presets (see the module docstring).
PRESETS = (
    "thesis", "telecentric", "thesis-3cam", "population", "thesis-platform", "thesis-real",
    "thesis-tip", "thesis-gripper",
)  # fmt: skip

#: The ``thesis-tip`` preset's tool: a patch pipette of 10 degrees with a 1 µm opening.
THESIS_TIP = "tip:pipette:10:1"
#: The ``thesis-tip`` shank's elevation above {G}'s x-y plane, degrees.
TOOL_ELEVATION_DEG = 20.0
#: The ``thesis-gripper`` preset's jaw beside the board: 30 degrees, a 40 µm rounded end.
THESIS_JAW = "tip:jaw:30:40"
#: The ``thesis-gripper`` jaw's shank: away from the board along {G}'s -x (across the
#: cameras' baseline, so that the cameras fix its tip along it), rising 10 degrees.
JAW_AZIMUTH_DEG = 180.0
JAW_ELEVATION_DEG = 10.0
#: What lies behind a tool (bright field: the light through the sample), as a reflectance.
BRIGHT_FIELD = 0.85

#: The ``thesis-real`` reversal error with memory: per joint five play operators of radii
#: 0.25-4 µm, equal weights: the reversal builds up over the first 8 µm after a turn.
THESIS_PLAY = PlayHysteresis(np.tile(play_radii_um(4.0), (3, 1)), np.full((3, 5), 0.2))
#: The ``thesis-real`` motion noise: a 20 nm scatter and a 50 nm stick-slip step per joint.
THESIS_MOTION = MotionNoise(scatter_um=(0.02, 0.02, 0.02), step_um=(0.05, 0.05, 0.05))

#: Where the motion noise draws from: its own stream per seed (``[seed, MOTION_STREAM]``),
#: so that turning it on changes no other draw.
MOTION_STREAM = 92830

#: The travel of the ``thesis-platform`` positioner, µm: x and y 0-6000 with 0.5 mm to spare,
#: as the manipulators'; it has no z drive, so its z joint is held at 0.
POSITIONER_LIMITS_UM = ((-500.0, 6500.0), (-500.0, 6500.0), (0.0, 0.0))

#: Angle of the ``front`` camera's axis from the side camera's, degrees.
FRONT_CAMERA_ANGLE_DEG = 35.0


def preset_config(preset: str) -> PlatformConfig:
    """The configuration a preset starts from (before any overrides).

    Raises
    ------
    InputError
        An unknown preset, naming the nearest.
    """
    if preset == ONE_CAMERA_PRESET:
        raise InputError(
            "preset 'patch' is the one-camera microscope, not a platform of cameras around the "
            'manipulator: open it as a rig (a rig file with preset = "patch"), build it '
            "with microcal.sim.patch.patch_rig(seed), or run microcal demo --preset patch"
        )
    if preset not in PRESETS:
        hint = did_you_mean(preset, PRESETS).strip()
        raise InputError(
            f"preset: expected one of {list(PRESETS)}, got {preset!r}"
            + (f" ({hint})" if hint else "")
        )
    config = PlatformConfig()
    if preset == "telecentric":
        config = dataclasses.replace(
            config,
            top=dataclasses.replace(
                config.top, projection="affine", dist=(1e-3, 0.0, 1e-4, -1e-4, 0.0)
            ),
            side=dataclasses.replace(
                config.side, projection="affine", dist=(8e-4, 0.0, -1e-4, 1e-4, 0.0)
            ),
        )
    elif preset == "thesis-3cam":
        config = dataclasses.replace(config, front=dataclasses.replace(config.side))
    elif preset in ("thesis-real", "population"):
        config = dataclasses.replace(
            config, manipulator=dataclasses.replace(config.manipulator, real_motion=True)
        )
    elif preset == "thesis-tip":
        config = dataclasses.replace(config, board=THESIS_TIP,
                                     tool_elevation_deg=TOOL_ELEVATION_DEG)  # fmt: skip
    elif preset == "thesis-gripper":
        config = dataclasses.replace(config, tool=THESIS_JAW, tool_elevation_deg=JAW_ELEVATION_DEG,
                                     tool_azimuth_deg=JAW_AZIMUTH_DEG)  # fmt: skip
    elif preset == "thesis-platform":
        config = dataclasses.replace(
            config,
            m2=ManipulatorConfig(),
            p1=ManipulatorConfig(limits_um=POSITIONER_LIMITS_UM, loop_settle_s=0.2),
        )
    return config


def _set_dotted(obj: Any, dotted: str, value: Any, full: str = "") -> Any:
    full = full or dotted
    head, _, rest = dotted.partition(".")
    names = [f.name for f in dataclasses.fields(obj)] if dataclasses.is_dataclass(obj) else []
    if head not in names:
        hint = did_you_mean(head, names)
        settings = f"({hint}settings here: {', '.join(names)})" if names else "(not a table)"
        raise InputError(f"override {full!r}: no setting {head!r} {settings}")
    current = getattr(obj, head)
    if rest and current is None:
        raise InputError(
            f"override {full!r}: there is no {head!r} on this preset (a preset with it: "
            f"{'thesis-3cam' if head == 'front' else 'thesis-platform'})"
        )
    if rest:
        return dataclasses.replace(obj, **{head: _set_dotted(current, rest, value, full)})
    if isinstance(current, tuple) and isinstance(value, list):
        value = tuple(tuple(v) if isinstance(v, list) else v for v in value)
    if (
        current is not None
        and not isinstance(value, type(current))
        and not (
            isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool)
        )
    ) or (isinstance(value, bool) and not isinstance(current, bool)):
        raise InputError(
            f"override {full!r}: expected {type(current).__name__}, got {type(value).__name__}"
        )
    try:
        return dataclasses.replace(obj, **{head: value})
    except InputError as exc:
        raise InputError(f"override {full!r}: {str(exc).partition(': ')[2]}") from None


def check_overrides(overrides: Mapping[str, object], preset: str = "thesis") -> PlatformConfig:
    """A preset's configuration with ``overrides`` applied: each name, type and range checked.

    Raises
    ------
    InputError
        ``override 'top.faults.drop_rate': expected a number >= 0 and <= 1, got 1.5``, or
        an unknown name (with the nearest one).
    """
    config = preset_config(preset)
    for key, value in overrides.items():
        config = _set_dotted(config, key, value)
    try:
        parse_spec(config.board)
    except InputError as exc:
        raise InputError(f"override 'board': {exc}") from None
    check_number("tool_elevation_deg", config.tool_elevation_deg, low=-89, high=89)
    check_number("tool_azimuth_deg", config.tool_azimuth_deg, low=-360, high=360)
    if config.tool:
        carried = parse_spec(config.tool)
        if not isinstance(carried, TipTarget) or isinstance(parse_spec(config.board), TipTarget):
            raise InputError(
                f"override 'tool': expected a tool's tip spec (tip:jaw) beside a board, got "
                f"{config.tool!r} beside {config.board!r}"
            )
    if not all(math.isfinite(v) for v in config.tool_offset_um) or len(config.tool_offset_um) != 3:
        raise InputError(
            f"override 'tool_offset_um': expected three finite numbers (µm), got "
            f"{list(config.tool_offset_um)}"
        )
    return config


class Scene:
    """What the cameras see: the board (or a tool) on an end-effector and an optional fixed
    target.

    With a tool (``tool``, for a tip target in ``board``) the tool is seen instead of the
    board: its tip point at the end-effector's true position, its shank along ``tool_axis``.

    With several devices (preset ``thesis-platform``), one board is seen at a time: that of
    the device moved last, or of the device :meth:`show` named after that. With a target
    stage, the calibration target on it is seen instead while the stage was moved more
    recently than every device (see :mod:`microcal.sim.stage`).
    """

    def __init__(
        self,
        manipulator: SimManipulator,
        board: Target | TipTarget,
        board_R: FloatArray,
        stage: SimStage | None = None,
        calibration_target: Target | None = None,
        others: dict[str, SimManipulator] | None = None,
        tool: ToolPlacement | None = None,
    ) -> None:
        self.manipulator = manipulator
        self.devices = {manipulator.name: manipulator, **(others or {})}
        self.board = board
        self.board_R = board_R
        self.show_board = True
        self.fixed: Placement | None = None
        self.stage = stage
        self.calibration_target = calibration_target
        self._shown: tuple[str, float] | None = None
        self.tool = tool  # its tip point is moved to the end-effector
        self.carried: CarriedTool | None = None  # a tool beside the board (thesis-gripper)

    def show(self, name: str, t_s: float) -> None:
        """From ``t_s`` on, the board of device ``name`` is seen (until a device moves)."""
        self._shown = (name, t_s)

    def visible(self) -> SimManipulator:
        """The device whose board is seen (the first when none has moved)."""
        last = max(self.devices.values(), key=lambda m: m.last_move_s)
        if self._shown is not None and self._shown[1] >= last.last_move_s:
            return self.devices[self._shown[0]]
        return last

    def board_placement(self, t_s: float) -> Placement | ToolPlacement:
        """The board, its inner-corner centroid at the seen end-effector's true position (a
        tool: its tip point there)."""
        p = self.visible().true_position_um(t_s)
        if self.tool is not None:
            return dataclasses.replace(self.tool, tip_um=p)
        assert isinstance(self.board, Target)  # a tip target comes with its tool
        return Placement(self.board, self.board_R, p - self.board_R @ self.board.centre_um)

    def __call__(self, t_s: float) -> list[Placement | ToolPlacement]:
        stage, target = self.stage, self.calibration_target
        moved_last = stage is not None and stage.last_move_s > max(
            m.last_move_s for m in self.devices.values()
        )
        if moved_last and stage is not None and target is not None:
            return [Placement(target, np.eye(3), stage.joints_um(t_s))]
        out: list[Placement | ToolPlacement] = [] if self.fixed is None else [self.fixed]
        if self.show_board:
            out.append(self.board_placement(t_s))
            if self.carried is not None and isinstance(out[-1], Placement):
                out.append(self.carried.at(out[-1]))
        return out


@dataclass
class SimPlatform:
    """The simulated platform; ``truth_*`` members are for tests and benchmarks only."""

    config: PlatformConfig
    clock: Clock
    manipulator: SimManipulator
    cameras: dict[str, SimCamera]
    scene: Scene
    seed: int
    target_stage: SimStage | None = None
    population: PopulationDraw | None = None  # the draw of a ``population`` platform

    @property
    def manipulators(self) -> dict[str, SimManipulator]:
        """Every device the vision system sees, by name (``m1`` first)."""
        return dict(self.scene.devices)

    @property
    def camera_models(self) -> dict[str, AnyCamera]:
        """The true camera models (ground truth)."""
        return {name: cam.model for name, cam in self.cameras.items()}

    def truth_position_um(self) -> FloatArray:
        """True end-effector position now, (3,) µm in {G}."""
        return self.manipulator.true_position_um()


def platform(
    preset: str = "thesis",
    seed: int = 0,
    overrides: Mapping[str, object] | None = None,
    clock: Clock | None = None,
) -> SimPlatform:
    """Build a simulated platform.

    Parameters
    ----------
    preset : str
        One of :data:`PRESETS`: ``"thesis"`` (the thesis's platform), ``"telecentric"``,
        ``"thesis-3cam"``, ``"population"`` (see the module docstring).
    seed : int
        Seed of every random draw (noise, faults, vibration); same seed, same frames.
    overrides : mapping, optional
        Dotted settings of :class:`PlatformConfig`, e.g. ``{"top.bit_depth": 12}``, each
        checked (name, type, range) by :func:`check_overrides`.
    clock : Clock, optional
        The platform's time; a :class:`SimClock` from 0 by default (the digital twin gives
        one that follows the wall clock).
    """
    from .thesis_kinematics import thesis_kinematics  # the preset builds on this package

    config = check_overrides(overrides or {}, preset)
    root = np.random.SeedSequence(seed)
    s_manip, s_top, s_side, s_front = root.spawn(4)  # the first three as with two cameras
    clock = SimClock() if clock is None else clock
    mc = config.manipulator
    n_cameras = 2 if config.front is None else 3
    draw = draw_population(root.spawn(1)[0], n_cameras) if preset == "population" else None
    truth = thesis_kinematics() if draw is None else draw.truth
    motion = None
    if mc.real_motion:
        play, motion = (THESIS_PLAY, THESIS_MOTION) if draw is None else (draw.play, draw.motion)
        truth = dataclasses.replace(truth, play=play)
    manipulator = SimManipulator(
        truth, clock, np.random.default_rng(s_manip),
        limits_um=mc.limits_um, speed_um_s=mc.speed_um_s, loop_settle_s=mc.loop_settle_s,
        sensor_noise_um=mc.sensor_noise_um, temperature_c=mc.temperature_c,
        temperature_drift_c_per_h=mc.temperature_drift_c_per_h
        + (0.0 if draw is None else draw.temperature_drift_c_per_h),
        faults=mc.faults, motion=motion, motion_rng=np.random.default_rng([seed, MOTION_STREAM]),
    )  # fmt: skip
    manipulator.mount_offset_um = np.array(mc.mount_offset_um, dtype=np.float64)
    manipulator.joint_scale = np.array(mc.joint_scale, dtype=np.float64)
    if draw is not None:  # each seed another unit, and the room's temperature cycle
        manipulator.unit = f"{preset} seed {seed}"
        manipulator.temperature_swing_c = draw.temperature_swing_c
        manipulator.temperature_period_h = draw.temperature_period_h
        manipulator.temperature_phase = draw.temperature_phase
    board = parse_spec(config.board)
    stage = SimStage(clock, np.random.default_rng(root.spawn(1)[0]))
    others = _further_devices(config, manipulator, clock, root)
    tool = None if isinstance(board, Target) else _tool_of(board, config)
    scene = Scene(
        manipulator, board, np.eye(3), stage, parse_target(config.calibration_target), others,
        tool,
    )  # fmt: skip
    if config.tool:
        tip = parse_spec(config.tool)
        assert isinstance(tip, TipTarget)  # checked with the overrides
        scene.carried = carried_tool(
            tip, np.array(config.tool_offset_um), config.tool_elevation_deg,
            config.tool_azimuth_deg,
        )  # fmt: skip
    reflectance = None if tool is None else Reflectance(background=BRIGHT_FIELD)
    top, side = thesis_cameras()
    views: list[tuple[CameraModel, CameraConfig, np.random.SeedSequence]] = [
        (top, config.top, s_top), (side, config.side, s_side)
    ]  # fmt: skip
    if config.front is not None:
        views.append((front_camera(side), config.front, s_front))
    if draw is not None:
        views = [
            (placed(model, draw.camera_rotation_deg[i], draw.camera_magnification[i]), cfg, seq)
            for i, (model, cfg, seq) in enumerate(views)
        ]
    cameras = {}
    for model, cfg, seq in views:
        focus = float(model.depth_um(TRAVEL_CENTRE_UM)[0])
        camera = _with_projection(model, cfg)
        formation = dataclasses.replace(cfg.formation, focus_depth_um=focus)
        cameras[camera.name] = SimCamera(
            camera, scene, clock, np.random.default_rng(seq), pixel_size_um=cfg.pixel_size_um,
            bit_depth=cfg.bit_depth, formation=formation, faults=cfg.faults,
            reflectance=reflectance,
        )  # fmt: skip
    return SimPlatform(config, clock, manipulator, cameras, scene, seed, stage, draw)


def _tool_of(target: TipTarget, config: PlatformConfig) -> ToolPlacement:
    """The simulated tool of a tip target (a pipette for ``any``; a taper of 10 degrees and a
    1 µm end where the spec gives none), its tip at the origin until placed."""
    tool = Tool(
        "pipette" if target.kind == "any" else target.kind,
        taper_deg=target.taper_deg or 10.0,
        tip_um=target.tip_um or 1.0,
    )
    axis = tool_axis(config.tool_elevation_deg, config.tool_azimuth_deg)
    return ToolPlacement(tool, np.zeros(3), axis)


def _further_devices(
    config: PlatformConfig, m1: SimManipulator, clock: Clock, root: np.random.SeedSequence
) -> dict[str, SimManipulator]:
    """The ``m2`` and ``p1`` a configuration has, each with its own random stream."""
    from .station_devices import positioner_kinematics, second_manipulator_kinematics

    out: dict[str, SimManipulator] = {}
    for name, mc in (("m2", config.m2), ("p1", config.p1)):
        seq = root.spawn(1)[0]  # spawned whether or not the device is there: seeds stay put
        if mc is None:
            continue
        truth = second_manipulator_kinematics(m1.truth) if name == "m2" else (
            positioner_kinematics())  # fmt: skip
        if mc.real_motion:
            truth = dataclasses.replace(truth, play=THESIS_PLAY)
        device = SimManipulator(
            truth, clock, np.random.default_rng(seq), name=name, limits_um=mc.limits_um,
            speed_um_s=mc.speed_um_s, loop_settle_s=mc.loop_settle_s,
            sensor_noise_um=mc.sensor_noise_um, temperature_c=mc.temperature_c,
            temperature_drift_c_per_h=mc.temperature_drift_c_per_h, faults=mc.faults,
            motion=THESIS_MOTION if mc.real_motion else None,
            motion_rng=np.random.default_rng(seq.spawn(1)[0]),
        )  # fmt: skip
        device.mount_offset_um = np.array(mc.mount_offset_um, dtype=np.float64)
        device.joint_scale = np.array(mc.joint_scale, dtype=np.float64)
        out[name] = device
    return out


#: The middle of the end-effector's travel in {G}, µm: where the cameras focus.
TRAVEL_CENTRE_UM = np.array([5000.0, 4800.0, 2700.0])


def _with_projection(model: CameraModel, cfg: CameraConfig) -> AnyCamera:
    """The camera of a configuration: the pinhole model with its distortion, or the affine
    camera of the same pose whose magnification is the pinhole's at the travel's middle."""
    if cfg.projection == "pinhole":
        return CameraModel(model.K, np.array(cfg.dist), model.R, model.t_um,
                           model.image_size_px, model.name)  # fmt: skip
    K = model.K.copy()
    K[:2, :2] /= float(model.depth_um(TRAVEL_CENTRE_UM)[0])
    return AffineCamera(K, np.array(cfg.dist), model.R, model.t_um, model.image_size_px,
                        model.name)  # fmt: skip


def placed(model: CameraModel, rotation_deg: FloatArray, magnification: float) -> CameraModel:
    """The camera turned about the travel's middle by ``rotation_deg`` (about {G}'s x, y, z,
    in that order, degrees) and its focal length scaled by ``magnification``."""
    Q = np.eye(3)
    for axis, angle in enumerate(np.radians(rotation_deg)):
        c, s = np.cos(angle), np.sin(angle)
        i, j = [a for a in range(3) if a != axis]
        turn = np.eye(3)
        turn[i, i] = turn[j, j] = c
        turn[i, j], turn[j, i] = -s, s
        Q = turn @ Q
    R = model.R @ Q
    t = model.R @ TRAVEL_CENTRE_UM + model.t_um - R @ TRAVEL_CENTRE_UM
    K = model.K.copy()
    K[:2, :2] *= magnification
    return CameraModel(K, model.dist, R, t, model.image_size_px, model.name)


def front_camera(side: CameraModel) -> CameraModel:
    """The ``thesis-3cam`` preset's third camera: the side camera's intrinsics and distance
    from the travel's middle, its axis turned by :data:`FRONT_CAMERA_ANGLE_DEG` about {G}'s
    x axis towards +y, its image x axis along {G}'s x as the other cameras' are."""
    a = np.radians(FRONT_CAMERA_ANGLE_DEG)
    c, s = np.cos(a), np.sin(a)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])  # about x, +z towards +y
    axis = turn @ side.R[2]
    distance = float(side.depth_um(TRAVEL_CENTRE_UM)[0])
    x = np.array([1.0, 0.0, 0.0]) - axis[0] * axis  # image x along {G}'s x, as the others'
    x /= np.linalg.norm(x)
    R = np.vstack([x, np.cross(axis, x), axis])
    t = -R @ (TRAVEL_CENTRE_UM - distance * axis)
    return CameraModel(side.K, np.zeros(5), R, t, side.image_size_px, "front")
