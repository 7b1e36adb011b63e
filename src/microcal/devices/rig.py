"""Open the devices a rig spec names: the simulator, or hardware drivers.

``open_rig(load_rig("myrig.toml"))`` gives a :class:`Rig` whose manipulator, cameras and clock
the procedures drive the same way whatever is behind them. Close it when done (it is a
context manager): it closes every device through its own ``close()``, then releases what the
rig holds besides (a Micro-Manager core).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

from .._validation import FloatArray
from ..errors import DeviceError, InputError
from ..vision.effector_target import parse_effector_target
from ..vision.targets import Target, parse_target
from ..vision.tip_target import TipTarget
from .base import Camera, Clock, Device, Manipulator, RealClock
from .held_axes import with_three_joints
from .rig_spec import (
    AravisCameraSpec,
    HardwareRigSpec,
    MCS2Spec,
    MMCameraSpec,
    MMStageSpec,
    RigSpec,
)

__all__ = [
    "Rig",
    "check_device_name",
    "open_hardware_rig",
    "platform_rig",
    "select_device",
]


@dataclass
class Rig:
    """The opened devices of a rig.

    Attributes
    ----------
    manipulator : Manipulator
    cameras : dict of str to Camera
        By the names the run uses, in order.
    clock : Clock
    board : Target or TipTarget
        The end-effector's target.
    temperature : callable () -> float, optional
        Ambient temperature now, °C (the simulator's; None when the rig has no sensor).
    truth : callable () -> (3,) float, optional
        The end-effector's true position now, µm in {G}: the simulator's ground truth, for
        tests and benchmarks (None for hardware).
    description : dict of str to str
        What answered, per device (for the dry run and the record).
    resources : list of callable
        Releases of what the rig holds besides its devices (a Micro-Manager core's
        ``unloadAllDevices``), called after the devices are closed, last first.
    target_stage : Manipulator, optional
        The stage carrying the camera-calibration target (None when the rig has none).
    calibration_target : Target, optional
        The target on it.
    manipulators : dict of str to Manipulator
        Every device the cameras measure, by the names calibrations use (``m1``, ``m2``,
        ``p1`` ...): ``manipulator`` is the :attr:`selected` one (see :meth:`select`).
    truths : dict of str to callable
        Each device's ground truth (the simulator's; empty for hardware).
    show : callable (str) -> None, optional
        Make the cameras see a device's target (the simulator shows one board at a time);
        None when every target is always in view.
    selected : str
        The name of ``manipulator``.
    temperatures : dict of str to callable
        Each device's ambient temperature sensor, where devices have their own (the
        simulator's); :meth:`select` makes it ``temperature``.
    boards : dict of str to Target or TipTarget
        Every device's target, by name, when devices carry targets of their own (a rig
        file's ``[manipulators.NAME]`` ``board``); :meth:`select` makes it ``board``. Empty
        when every device carries ``board``.
    microscope : Manipulator, optional
        The microscope's X-Y stage and focus drive as joints x, y, z (a rig file's
        ``[microscope]``); None when the rig names none.
    """

    manipulator: Manipulator
    cameras: dict[str, Camera]
    clock: Clock
    board: Target | TipTarget
    temperature: Callable[[], float] | None = None
    truth: Callable[[], FloatArray] | None = None
    description: dict[str, str] = field(default_factory=dict)
    resources: list[Callable[[], None]] = field(default_factory=list)
    target_stage: Manipulator | None = None
    calibration_target: Target | None = None
    manipulators: dict[str, Manipulator] = field(default_factory=dict)
    truths: dict[str, Callable[[], FloatArray]] = field(default_factory=dict)
    show: Callable[[str], None] | None = None
    selected: str = "m1"
    temperatures: dict[str, Callable[[], float]] = field(default_factory=dict)
    boards: dict[str, Target | TipTarget] = field(default_factory=dict)
    microscope: Manipulator | None = None
    _closed: bool = field(default=False, init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.manipulators:
            self.manipulators = {self.selected: self.manipulator}

    def select(self, name: str | None) -> Rig:
        """The rig with device ``name`` as its manipulator (and truth); None: as it is.

        The result shares the devices (closing either closes them all).

        Raises
        ------
        InputError
            A name the rig has no device of, naming those it has.
        """
        if name is None or name == self.selected:
            return self
        if name not in self.manipulators:
            raise unknown_device(name, tuple(self.manipulators))
        return dataclasses.replace(
            self, manipulator=self.manipulators[name], truth=self.truths.get(name), selected=name,
            temperature=self.temperatures.get(name, self.temperature),
            board=self.boards.get(name, self.board),
        )  # fmt: skip

    def for_calibration(self, name: str) -> Rig:
        """The rig with the device a calibration entry ``name`` is for: the one of that name,
        or a rig's only device whatever the calibration calls it (the device's identity is
        checked against the calibration's by whoever uses it)."""
        return self if len(self.manipulators) == 1 else self.select(name)

    def look_at(self) -> None:
        """Make the cameras see the selected device's target (see ``show``)."""
        if self.show is not None:
            self.show(self.selected)

    @property
    def sensors(self) -> dict[str, Callable[[], float]]:
        """The rig's sensors of a model's extra inputs, by registry name."""
        return {} if self.temperature is None else {"temperature": self.temperature}

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has been called."""
        return self._closed

    def close(self) -> None:
        """Close every device, then release the rig's resources; again, it does nothing.

        Every device is closed even when closing another fails.

        Raises
        ------
        DeviceError
            Closing something failed (named), after everything else was closed.
        """
        if self._closed:
            return
        self._closed = True
        devices: list[tuple[str, Device]] = [*self.cameras.items()]
        devices += [
            ("manipulator" if len(self.manipulators) == 1 else f"manipulator {n}", m)
            for n, m in self.manipulators.items()
        ]
        if self.target_stage is not None:
            devices.append(("target stage", self.target_stage))
        if self.microscope is not None:
            devices.append(("microscope", self.microscope))
        failed = _close_all(devices, self.resources)
        self.resources.clear()
        if failed:
            raise DeviceError(
                f"rig: closing {'; '.join(failed)} failed; everything else was closed"
            )

    def __enter__(self) -> Rig:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
            return
        with contextlib.suppress(DeviceError):  # the error that ended the block is the news
            self.close()


def unknown_device(name: str, names: tuple[str, ...]) -> InputError:
    """The error of ``--manipulator NAME`` on a rig whose devices are ``names``."""
    return InputError(
        f"--manipulator {name}: this rig has no such device (it has {', '.join(names)})"
    )


def _close_all(devices: list[tuple[str, Device]], resources: list[Callable[[], None]]) -> list[str]:
    """Close the devices in order, then release the resources last first; what failed."""
    failed: list[str] = []
    for name, device in devices:
        try:
            device.close()
        except Exception as exc:  # closing goes on whatever one device does
            failed.append(f"{name} ({exc})")
    for release in reversed(resources):
        try:
            release()
        except Exception as exc:
            failed.append(f"{getattr(release, '__qualname__', 'a resource')} ({exc})")
    return failed


def select_device(rig: Rig, spec: RigSpec, manipulator: str | None = None) -> Rig:
    """The opened ``rig`` with ``manipulator`` selected, looking at it (the first device by
    default); raises InputError, before anything is opened, for a name the spec lacks."""
    check_device_name(spec, manipulator)
    rig = rig.select(manipulator)
    rig.look_at()  # what the cameras see first is the device the caller works with
    return rig


def check_device_name(spec: RigSpec, manipulator: str | None) -> None:
    """Raise InputError when ``manipulator`` names no device of the rig spec."""
    if manipulator is not None and manipulator not in spec.manipulator_names:
        raise unknown_device(manipulator, spec.manipulator_names)


def open_hardware_rig(spec: HardwareRigSpec, manipulator: str | None = None) -> Rig:
    """Open the hardware devices of a rig spec (``formats.rig_file.load_rig``'s result).

    A simulated rig (``SimRigSpec``) is opened by ``workflows.rigs.open_rig``, which opens
    either kind.

    Parameters
    ----------
    spec : HardwareRigSpec
    manipulator : str, optional
        The device the rig's ``manipulator`` is (:meth:`Rig.select`); the first by default.

    Raises
    ------
    InputError
        ``manipulator`` names no device of the rig (nothing is opened).
    DeviceError
        A device that cannot be reached or set up; the message names it. Whatever was
        opened before it is closed again.
    """
    if not isinstance(spec, HardwareRigSpec):
        raise DeviceError(
            f"rig: expected a HardwareRigSpec (formats.rig_file.load_rig), "
            f"got {type(spec).__name__}"
        )
    check_device_name(spec, manipulator)
    return select_device(_hardware(spec), spec, manipulator)


def platform_rig(plat: Any, description: str = "simulated") -> Rig:
    """The rig of a simulated platform (``microcal.sim.platform``'s result), every device
    with its ground truth; ``manipulator`` is ``m1``."""
    devices = plat.manipulators

    def truth_of(m: Any) -> Callable[[], FloatArray]:
        return lambda: m.true_position_um()

    def temperature_of(m: Any) -> Callable[[], float]:
        return lambda: m.temperature_at(plat.clock.now_s())

    return Rig(
        plat.manipulator,
        dict(plat.cameras),
        plat.clock,
        plat.scene.board,
        temperature=temperature_of(plat.manipulator),
        truth=plat.truth_position_um,
        description={"platform": description},
        target_stage=plat.target_stage,
        calibration_target=parse_target(plat.config.calibration_target),
        manipulators=dict(devices),
        truths={name: truth_of(m) for name, m in devices.items()},
        temperatures={name: temperature_of(m) for name, m in devices.items()},
        show=None if len(devices) == 1 else lambda n: plat.scene.show(n, plat.clock.now_s()),
    )


def _hardware(spec: HardwareRigSpec) -> Rig:
    opened: list[tuple[str, Device]] = []  # closed again, last first, if a later one fails
    resources: list[Callable[[], None]] = []
    try:
        return _open_hardware(spec, opened, resources)
    except BaseException:
        _close_all(opened[::-1], resources)
        raise


def _open_hardware(
    spec: HardwareRigSpec,
    opened: list[tuple[str, Device]],
    resources: list[Callable[[], None]],
) -> Rig:
    description: dict[str, str] = {}
    core: Any = None
    if spec.micromanager is not None:
        from .micromanager import open_core

        mm = spec.micromanager
        core = open_core(mm.config, mm.python_devices, mm.options)
        resources.append(core.unloadAllDevices)
    manipulator = _open_manipulator(spec.manipulator, core, description)
    opened.append(("manipulator", manipulator))
    devices: dict[str, Manipulator] = {"m1": manipulator}
    for name, m_spec in spec.manipulators.items():
        devices[name] = _open_manipulator(m_spec, core, description, name)
        opened.append((f"manipulator {name}", devices[name]))
    stage = None
    if spec.target_stage is not None:
        stage = _open_manipulator(spec.target_stage, core, description, "target_stage")
        opened.append(("target stage", stage))
    scope = None
    if spec.microscope is not None:
        scope = _open_manipulator(spec.microscope, core, description, "microscope")
        opened.append(("microscope", scope))
    cameras: dict[str, Camera] = {}
    for name, cam_spec in spec.cameras.items():
        cameras[name] = _open_camera(name, cam_spec, core, description)
        opened.append((name, cameras[name]))
    boards = {n: parse_effector_target(spec.board_of(n)) for n in devices} if spec.boards else {}
    return Rig(
        manipulator,
        cameras,
        RealClock(),
        parse_effector_target(spec.board),
        description=description,
        resources=resources,
        target_stage=stage,
        calibration_target=None if stage is None else parse_target(str(spec.calibration_target)),
        manipulators=devices,
        boards=boards,
        microscope=scope,
    )


def _open_manipulator(
    m: MCS2Spec | MMStageSpec, core: Any, description: dict[str, str], role: str = "manipulator"
) -> Manipulator:
    if isinstance(m, MCS2Spec):
        from .smaract_mcs2 import MCS2Manipulator

        mcs2 = MCS2Manipulator(
            m.address,
            m.channels,
            m.limits_array(),
            port=m.port,
            timeout_s=m.timeout_s,
            reconnects=m.reconnects,
            speed_um_s=m.speed_um_s,
            name="mcs2" if role == "manipulator" else role,
        )
        try:
            mcs2.connect()
        except BaseException:
            mcs2.close()
            raise
        description[role] = f"SmarAct MCS2 {mcs2.serial} at {m.address}"
        return with_three_joints(mcs2)
    from .micromanager import MMManipulator

    stage = MMManipulator(
        core,
        xy_stage=m.xy_stage,
        focus=m.focus,
        limits_um=m.limits_array(),
        name="mm" if role == "manipulator" else role,
    )
    description[role] = stage.identity
    return with_three_joints(stage)


def _open_camera(
    name: str, c: AravisCameraSpec | MMCameraSpec, core: Any, description: dict[str, str]
) -> Camera:
    if isinstance(c, AravisCameraSpec):
        from .aravis_camera import AravisCamera

        cam = AravisCamera(
            c.address,
            name=name,
            exposure_s=c.exposure_s,
            pixel_format=c.pixel_format,
            region_px=c.region_px,
            timeout_s=c.timeout_s,
            pixel_size_um=c.pixel_size_um,
        )
        description[name] = f"{cam.vendor} {cam.serial} at {c.address}"
        return cam
    from .micromanager import MMCamera

    mm_cam = MMCamera(
        core, c.device, name=name, exposure_s=c.exposure_s, pixel_size_um=c.pixel_size_um
    )
    description[name] = f"Micro-Manager camera {c.device}"
    return mm_cam
