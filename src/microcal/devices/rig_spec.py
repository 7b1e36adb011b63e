"""What a rig is made of, as typed values: the simulator, or hardware devices and their settings.

A rig file (``formats.rig_file.load_rig``) gives one of these specs, ``workflows.rigs.open_rig``
opens the devices a spec names, and :meth:`~HardwareRigSpec.to_dict` is the rig's record in a
run's ``run.json`` (a resumed run must come from an equal record). The defaults of every
setting live here and only here.

Each spec checks itself on construction and raises :class:`InputError` naming the setting
(``limits_um: ...``), so a spec built in Python is as safe to open as one read from a file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from .._validation import FloatArray, name_problem
from ..errors import InputError
from ..json_value import JsonValue
from .aravis_camera import PIXEL_FORMATS  # the driver's module loads Aravis only when opened
from .held_axes import axes_in_order
from .smaract_mcs2 import MCS2_PORT

__all__ = [
    "ARAVIS_DEFAULT_EXPOSURE_MS",
    "DEFAULT_BOARD",
    "LEGACY_MM_CAMERA_RECORD",
    "LEGACY_MM_STAGE_RECORD",
    "AravisCameraSpec",
    "CameraSpec",
    "HardwareRigSpec",
    "MCS2Spec",
    "MMCameraSpec",
    "MMStageSpec",
    "ManipulatorSpec",
    "MicroManagerSpec",
    "RigSpec",
    "SimRigSpec",
]

#: The end-effector's board when a rig names none.
DEFAULT_BOARD = "chessboard:4x3:400"
#: Exposure of an Aravis camera whose spec gives none, ms.
ARAVIS_DEFAULT_EXPOSURE_MS = 10.0

# Settings that run.json records held before the specs were typed, for devices they do not
# apply to (their defaults then); written again so that those runs can still be resumed.
LEGACY_MM_STAGE_RECORD: dict[str, JsonValue] = {
    "port": MCS2_PORT,
    "timeout_s": 2.0,
    "reconnects": 2,
}
LEGACY_MM_CAMERA_RECORD: dict[str, JsonValue] = {"pixel_format": "Mono8", "timeout_s": 2.0}


def _positive(name: str, value: object) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]  # anything else is refused below
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, bool) or not (math.isfinite(v) and v > 0):
        raise InputError(f"{name}: expected a finite number > 0, got {value!r}")
    return v


def _integer(name: str, value: object, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InputError(f"{name}: expected an integer, got {value!r}")
    v = int(value)
    if v < low or (high is not None and v > high):
        bounds = f">= {low}" if high is None else f"{low}-{high}"
        raise InputError(f"{name}: expected an integer {bounds}, got {v}")
    return v


def _limits(value: Mapping[str, Any], axes: tuple[str, ...]) -> dict[str, tuple[float, float]]:
    if sorted(value) != sorted(axes):
        raise InputError(
            f"limits_um: expected a [low, high] for each of {list(axes)}, got {sorted(value)}"
        )
    out: dict[str, tuple[float, float]] = {}
    for axis in axes:
        pair = tuple(float(v) for v in value[axis])
        if len(pair) != 2 or not all(math.isfinite(v) for v in pair) or pair[0] >= pair[1]:
            raise InputError(
                f"limits_um.{axis}: expected [low, high] with low < high, got {list(value[axis])}"
            )
        out[axis] = (pair[0], pair[1])
    return out


def _limits_record(limits: Mapping[str, tuple[float, float]]) -> dict[str, list[float]]:
    return {axis: list(pair) for axis, pair in limits.items()}


@dataclass(frozen=True)
class SimRigSpec:
    """The simulated platform (``microcal.sim.platform``).

    Attributes
    ----------
    preset : str
        The platform preset (``"thesis"``).
    seed : int
        Seed of every random stream of the platform.
    overrides : mapping of str to value
        Settings of ``microcal.sim.PlatformConfig`` by dotted name,
        e.g. ``{"top.faults.drop_rate": 0.1}`` (checked when the platform is built).
    """

    driver: ClassVar[str] = "sim"

    preset: str = "thesis"
    seed: int = 0
    overrides: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "preset", str(self.preset))
        object.__setattr__(self, "seed", _integer("seed", self.seed, 0))
        object.__setattr__(self, "overrides", dict(self.overrides))

    @property
    def manipulator_names(self) -> tuple[str, ...]:
        """The devices the preset has (``m1``; ``m1, m2, p1`` for ``thesis-platform``)."""
        return ("m1", "m2", "p1") if self.preset == "thesis-platform" else ("m1",)

    def to_dict(self) -> dict[str, object]:
        """The rig's record (JSON types; the overrides as given), as stored in ``run.json``."""
        return {
            "driver": self.driver,
            "preset": self.preset,
            "seed": self.seed,
            "overrides": dict(self.overrides),
        }


@dataclass(frozen=True)
class MCS2Spec:
    """A SmarAct MCS2 controller (``devices.smaract_mcs2.MCS2Manipulator``).

    Attributes
    ----------
    address : str
        The controller's IP address or host name.
    channels : mapping of axis to int
        Controller channel of each axis, axes among x, y, z in that order; ``{x, y}`` alone
        is an X-Y positioner (its z joint held at 0, see ``devices.held_axes``).
    limits_um : mapping of axis to (low, high)
        Soft limits per axis, µm.
    port : int
        TCP port of the ASCII interface.
    timeout_s : float
        Longest wait for one answer, s.
    reconnects : int
        How often a lost connection is opened again before giving up.
    speed_um_s : float or None
        Channel speed set on connecting (None: the controller's own setting).
    """

    kind: ClassVar[str] = "smaract-mcs2"

    address: str
    channels: Mapping[str, int]
    limits_um: Mapping[str, tuple[float, float]]
    port: int = MCS2_PORT
    timeout_s: float = 2.0
    reconnects: int = 2
    speed_um_s: float | None = None

    def __post_init__(self) -> None:
        if not self.channels:
            raise InputError("channels: expected a channel per axis, e.g. {x = 0, y = 1, z = 2}")
        channels = {str(a): _integer(f"channels.{a}", c, 0) for a, c in self.channels.items()}
        if not axes_in_order(list(channels)):
            raise InputError(
                f"channels: expected axes among x, y, z in that order (x and y alone for an "
                f"X-Y positioner), got {list(channels)}"
            )
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "limits_um", _limits(self.limits_um, self.axes))
        object.__setattr__(self, "port", _integer("port", self.port, 1, 65535))
        object.__setattr__(self, "timeout_s", _positive("timeout_s", self.timeout_s))
        object.__setattr__(self, "reconnects", _integer("reconnects", self.reconnects, 0))
        if self.speed_um_s is not None:
            object.__setattr__(self, "speed_um_s", _positive("speed_um_s", self.speed_um_s))

    @property
    def axes(self) -> tuple[str, ...]:
        """The joints, in order (the keys of :attr:`channels`)."""
        return tuple(self.channels)

    def limits_array(self) -> FloatArray:
        """The soft limits in joint order, (n_axes, 2) µm."""
        return np.array([self.limits_um[a] for a in self.axes], dtype=np.float64)

    def to_dict(self) -> dict[str, JsonValue]:
        """The manipulator's record (JSON types)."""
        out: dict[str, JsonValue] = {
            "kind": self.kind,
            "limits_um": _limits_record(self.limits_um),
            "address": self.address,
            "port": self.port,
            "channels": dict(self.channels),
            "timeout_s": self.timeout_s,
            "reconnects": self.reconnects,
        }
        if self.speed_um_s is not None:
            out["speed_um_s"] = self.speed_um_s
        return out


@dataclass(frozen=True)
class MMStageSpec:
    """An XY stage and a focus stage of the Micro-Manager core as joints x, y, z; or an XY
    stage alone, an X-Y positioner (joints x, y; its z held at 0, see ``devices.held_axes``).

    Attributes
    ----------
    xy_stage : str
        Device label in the Micro-Manager configuration.
    limits_um : mapping of axis to (low, high)
        Soft limits of x, y and z (x and y without a focus stage), µm.
    focus : str or None
        Device label of the focus stage; None for an X-Y positioner.
    """

    kind: ClassVar[str] = "micromanager"

    xy_stage: str
    limits_um: Mapping[str, tuple[float, float]]
    focus: str | None = None

    def __post_init__(self) -> None:
        if self.focus is None and isinstance(self.limits_um, Mapping) and "z" in self.limits_um:
            raise InputError(
                "focus: the limits give z but no focus stage is named; name the focus device, "
                "or leave z out for an X-Y stage"
            )
        object.__setattr__(self, "limits_um", _limits(self.limits_um, self.axes))

    @property
    def axes(self) -> tuple[str, ...]:
        """``x, y, z``, or ``x, y`` without a focus stage."""
        return ("x", "y", "z") if self.focus is not None else ("x", "y")

    def limits_array(self) -> FloatArray:
        """The soft limits in joint order, (n_axes, 2) µm."""
        return np.array([self.limits_um[a] for a in self.axes], dtype=np.float64)

    def to_dict(self) -> dict[str, JsonValue]:
        """The manipulator's record (JSON types)."""
        return {
            "kind": self.kind,
            "limits_um": _limits_record(self.limits_um),
            **LEGACY_MM_STAGE_RECORD,
            "xy_stage": self.xy_stage,
            **({"focus": self.focus} if self.focus is not None else {}),
        }


@dataclass(frozen=True)
class AravisCameraSpec:
    """A GigE Vision / USB3 Vision camera through Aravis (``devices.aravis_camera``).

    Attributes
    ----------
    address : str
        The camera's IP address (or Aravis device id).
    exposure_ms : float or None
        Exposure, ms (None: :data:`ARAVIS_DEFAULT_EXPOSURE_MS`).
    pixel_format : str
        One of ``devices.aravis_camera.PIXEL_FORMATS``.
    region_px : (x, y, width, height) or None
        Sensor region to read (None: the whole sensor).
    timeout_s : float
        Longest wait for one frame, s.
    pixel_size_um : float
        The sensor's pixel pitch, µm.
    """

    kind: ClassVar[str] = "aravis"

    address: str
    exposure_ms: float | None = None
    pixel_format: str = "Mono8"
    region_px: tuple[int, int, int, int] | None = None
    timeout_s: float = 2.0
    pixel_size_um: float = 3.45

    def __post_init__(self) -> None:
        if self.exposure_ms is not None:
            object.__setattr__(self, "exposure_ms", _positive("exposure_ms", self.exposure_ms))
        if self.pixel_format not in PIXEL_FORMATS:
            raise InputError(
                f"pixel_format: expected one of {', '.join(PIXEL_FORMATS)}, "
                f"got {self.pixel_format!r}"
            )
        if self.region_px is not None:
            region = tuple(_integer("region_px", v, 0) for v in self.region_px)
            if len(region) != 4 or min(region[2:]) <= 0:
                raise InputError(
                    f"region_px: expected [x, y, width, height] with x, y >= 0 and a positive "
                    f"size, got {list(self.region_px)}"
                )
            object.__setattr__(self, "region_px", region)
        object.__setattr__(self, "timeout_s", _positive("timeout_s", self.timeout_s))
        object.__setattr__(self, "pixel_size_um", _positive("pixel_size_um", self.pixel_size_um))

    @property
    def exposure_s(self) -> float:
        """The exposure to set, s."""
        ms = ARAVIS_DEFAULT_EXPOSURE_MS if self.exposure_ms is None else self.exposure_ms
        return ms / 1e3

    def to_dict(self) -> dict[str, JsonValue]:
        """The camera's record (JSON types)."""
        out: dict[str, JsonValue] = {"kind": self.kind, "address": self.address}
        if self.exposure_ms is not None:
            out["exposure_ms"] = self.exposure_ms
        out["pixel_format"] = self.pixel_format
        if self.region_px is not None:
            out["region_px"] = list(self.region_px)
        out |= {"timeout_s": self.timeout_s, "pixel_size_um": self.pixel_size_um}
        return out


@dataclass(frozen=True)
class MMCameraSpec:
    """A camera of the Micro-Manager core (``devices.micromanager.MMCamera``).

    Attributes
    ----------
    device : str
        The camera's label in the Micro-Manager configuration.
    exposure_ms : float or None
        Exposure, ms (None: keep the camera's own).
    pixel_size_um : float
        The sensor's pixel pitch, µm.
    """

    kind: ClassVar[str] = "micromanager"

    device: str
    exposure_ms: float | None = None
    pixel_size_um: float = 3.45

    def __post_init__(self) -> None:
        if self.exposure_ms is not None:
            object.__setattr__(self, "exposure_ms", _positive("exposure_ms", self.exposure_ms))
        object.__setattr__(self, "pixel_size_um", _positive("pixel_size_um", self.pixel_size_um))

    @property
    def exposure_s(self) -> float | None:
        """The exposure to set, s (None: keep the camera's own)."""
        return None if self.exposure_ms is None else self.exposure_ms / 1e3

    def to_dict(self) -> dict[str, JsonValue]:
        """The camera's record (JSON types)."""
        out: dict[str, JsonValue] = {"kind": self.kind, "device": self.device}
        if self.exposure_ms is not None:
            out["exposure_ms"] = self.exposure_ms
        return out | LEGACY_MM_CAMERA_RECORD | {"pixel_size_um": self.pixel_size_um}


@dataclass(frozen=True)
class MicroManagerSpec:
    """The Micro-Manager core: a configuration file or pure-Python devices, exactly one.

    Attributes
    ----------
    config : str or None
        A Micro-Manager configuration file (``.cfg``, C++ device adapters).
    python_devices : str or None
        ``"module:function"``, a function that loads pure-Python devices into a ``UniMMCore``.
    options : mapping of str to str, int or float
        Keyword arguments of that function (``function(core, **options)``), e.g. the address
        of a frame source; empty by default.
    """

    config: str | None = None
    python_devices: str | None = None
    options: Mapping[str, str | int | float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if (self.config is None) == (self.python_devices is None):
            raise InputError(
                "micromanager: give exactly one of 'config' (a .cfg file) or "
                "'python_devices' (module:function)"
            )
        object.__setattr__(self, "options", dict(self.options))
        if self.options and self.python_devices is None:
            raise InputError("micromanager.options: only 'python_devices' takes options")

    def to_dict(self) -> dict[str, JsonValue]:
        """The core's record (JSON types)."""
        if self.config is not None:
            return {"config": self.config}
        out: dict[str, JsonValue] = {"python_devices": self.python_devices}
        return out | ({"options": dict(self.options)} if self.options else {})


ManipulatorSpec = MCS2Spec | MMStageSpec
CameraSpec = AravisCameraSpec | MMCameraSpec


@dataclass(frozen=True)
class HardwareRigSpec:
    """Real devices: one manipulator, two or more cameras, the board and the Micro-Manager core.

    Attributes
    ----------
    manipulator : MCS2Spec or MMStageSpec
    cameras : mapping of name to AravisCameraSpec or MMCameraSpec
        Two or more cameras, by the names the run uses (``top``, ``side`` ...), in order.
    board : str
        The end-effector's target: a board or a tool's tip (``tip:needle:20:5``;
        ``microcal.vision.effector_target.parse_effector_target``).
    micromanager : MicroManagerSpec or None
        Needed when a device is a Micro-Manager one.
    target_stage : MCS2Spec or MMStageSpec or None
        The stage that carries the camera-calibration target (``stereo-calibrate --rig``
        moves it by the known steps of method (a)); None when the rig has none.
    calibration_target : str or None
        The target on that stage (e.g. ``dotgrid:40x30:250``); given with the stage.
    manipulators : mapping of str to MCS2Spec or MMStageSpec
        Further devices in the cameras' view (a second manipulator, the sample's
        positioner), by the names calibrations use; ``manipulator`` is ``m1``.
    microscope : MMStageSpec or None
        The microscope's X-Y stage and focus drive (Micro-Manager's XY stage and focus
        devices, joints x, y, z): what ``scope-calibrate`` moves. A rig of one camera needs
        it with its focus device (depth comes from focus).
    boards : mapping of str to str
        The further devices that carry a target of their own (``[manipulators.NAME]``'s
        ``board``), by name; the others carry ``board``. Targets that can be told apart in
        one image (ChArUco boards with their own markers) let several devices be in view.
    """

    driver: ClassVar[str] = "hardware"

    manipulator: ManipulatorSpec
    cameras: Mapping[str, CameraSpec]
    board: str = DEFAULT_BOARD
    micromanager: MicroManagerSpec | None = None
    target_stage: ManipulatorSpec | None = None
    calibration_target: str | None = None
    manipulators: Mapping[str, ManipulatorSpec] = field(default_factory=dict)
    boards: Mapping[str, str] = field(default_factory=dict)
    microscope: MMStageSpec | None = None

    def __post_init__(self) -> None:
        from ..vision.effector_target import parse_effector_target

        object.__setattr__(self, "cameras", dict(self.cameras))
        object.__setattr__(self, "manipulators", dict(self.manipulators))
        object.__setattr__(self, "boards", dict(self.boards))
        for name, spec in self.boards.items():
            if name not in self.manipulators:
                raise InputError(
                    f"boards.{name}: no such further device (the board of m1 is 'board')"
                )
            if not isinstance(spec, str):
                raise InputError(f"boards.{name}: expected a target spec string, got {spec!r}")
            parse_effector_target(spec)
        for name in self.cameras:
            problem = name_problem(name)
            if problem is not None:  # it becomes a file name (images/NAME_0001.tiff)
                raise InputError(f"cameras: {problem}; name the camera e.g. top or side")
        for name in self.manipulators:
            if name_problem(name) is not None:
                raise InputError(f"manipulators: {name_problem(name)}; name it e.g. m2 or p1")
            taken = name in ("m1", "manipulator", "target_stage") or name in self.cameras
            if taken or not name.replace("_", "").replace("-", "").isalnum():
                raise InputError(
                    f"manipulators.{name}: expected a name such as m2 or p1 (letters, digits, "
                    "- and _; not m1, which is [manipulator], nor a camera's name)"
                )
        one_camera = len(self.cameras) == 1
        if one_camera and (self.microscope is None or self.microscope.focus is None):
            raise InputError(
                "cameras: expected two cameras or more (e.g. [cameras.top], [cameras.side]), "
                "or one camera with the microscope's focus device: add [microscope] with "
                'focus = "ZStage" (its Micro-Manager label), xy_stage and limits_um'
            )
        if len(self.cameras) < 2 and not one_camera:
            raise InputError(
                f"cameras: expected two cameras or more (e.g. [cameras.top], [cameras.side]), "
                f"got {len(self.cameras)}"
            )
        if self.uses_micromanager and self.micromanager is None:
            raise InputError(
                "micromanager: Micro-Manager devices need the core: give 'config' (a .cfg "
                "file) or 'python_devices' (module:function)"
            )
        if (self.target_stage is None) != (self.calibration_target is None):
            raise InputError(
                "target_stage: give the stage and the target it carries together "
                '([target_stage] and calibration_target = "dotgrid:40x30:250", say)'
            )

    @property
    def uses_micromanager(self) -> bool:
        """True when a device is a Micro-Manager one."""
        stages = (self.manipulator, self.target_stage, self.microscope,
                  *self.manipulators.values())  # fmt: skip
        return any(isinstance(s, MMStageSpec) for s in stages) or any(
            isinstance(c, MMCameraSpec) for c in self.cameras.values()
        )

    def to_dict(self) -> dict[str, JsonValue]:
        """The rig's record (JSON types), as stored in ``run.json``."""
        out: dict[str, JsonValue] = {
            "driver": self.driver,
            "board": self.board,
            "manipulator": self.manipulator.to_dict(),
            "cameras": {name: cam.to_dict() for name, cam in self.cameras.items()},
        }
        if self.micromanager is not None:
            out["micromanager"] = self.micromanager.to_dict()
        if self.target_stage is not None:
            out["target_stage"] = self.target_stage.to_dict()
            out["calibration_target"] = self.calibration_target
        if self.manipulators:
            out["manipulators"] = {
                n: m.to_dict() | ({"board": self.boards[n]} if n in self.boards else {})
                for n, m in self.manipulators.items()
            }
        if self.microscope is not None:
            out["microscope"] = self.microscope.to_dict()
        return out

    @property
    def manipulator_names(self) -> tuple[str, ...]:
        """``m1`` (the ``[manipulator]``) and the further devices' names."""
        return ("m1", *self.manipulators)

    def board_of(self, name: str) -> str:
        """The target device ``name`` carries: its own, or the rig's ``board``."""
        return self.boards.get(name, self.board)


RigSpec = SimRigSpec | HardwareRigSpec
