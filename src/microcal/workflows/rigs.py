"""Open a rig named by a rig spec: the simulator or hardware drivers, as the spec says."""

from __future__ import annotations

from ..devices.rig import Rig, check_device_name, open_hardware_rig, platform_rig, select_device
from ..devices.rig_spec import HardwareRigSpec, RigSpec, SimRigSpec
from ..errors import DeviceError
from ..sim import platform

__all__ = ["open_rig"]


def open_rig(spec: RigSpec, manipulator: str | None = None) -> Rig:
    """Open the devices of a rig (``formats.rig_file.load_rig``'s result).

    Parameters
    ----------
    spec : SimRigSpec or HardwareRigSpec
    manipulator : str, optional
        The device the rig's ``manipulator`` is (``Rig.select``); the first by default.

    Raises
    ------
    InputError
        ``manipulator`` names no device of the rig (nothing is opened).
    DeviceError
        A device that cannot be reached or set up; the message names it. Whatever was
        opened before it is closed again.
    """
    if isinstance(spec, HardwareRigSpec):
        return open_hardware_rig(spec, manipulator)
    if isinstance(spec, SimRigSpec):
        check_device_name(spec, manipulator)
        plat = platform(spec.preset, seed=spec.seed, overrides=dict(spec.overrides))
        rig = platform_rig(plat, f"simulated, preset {spec.preset}, seed {spec.seed}")
        return select_device(rig, spec, manipulator)
    raise DeviceError(
        f"rig: expected a SimRigSpec or HardwareRigSpec (formats.rig_file.load_rig), "
        f"got {type(spec).__name__}"
    )
