"""Open a rig named by a rig spec: the simulator or hardware drivers, as the spec says."""

from __future__ import annotations

from ..devices.rig import Rig, check_device_name, open_hardware_rig, platform_rig, select_device
from ..devices.rig_spec import HardwareRigSpec, RigSpec, SimRigSpec
from ..errors import DeviceError
from ..sim import platform
from ..sim.patch import PatchRig
from ..sim.patch_devices import patch_as_rig, patch_config
from ..sim.platforms import ONE_CAMERA_PRESET

__all__ = ["open_rig"]


def open_rig(spec: RigSpec, manipulator: str | None = None) -> Rig:
    """Open the devices of a rig (``formats.rig_file.load_rig``'s result).

    Parameters
    ----------
    spec : SimRigSpec or HardwareRigSpec
        A simulated rig of preset ``patch`` is the one-camera microscope
        (:func:`~microcal.sim.patch_devices.patch_as_rig`: one camera ``scope``, the stage
        and focus as ``microscope``); any other preset a platform of cameras.
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
        where = f"simulated, preset {spec.preset}, seed {spec.seed}"
        if spec.preset == ONE_CAMERA_PRESET:  # one camera on a focus drive
            patch = PatchRig(patch_config(spec.overrides), spec.seed)
            return select_device(patch_as_rig(patch, where), spec, manipulator)
        plat = platform(spec.preset, seed=spec.seed, overrides=dict(spec.overrides))
        rig = platform_rig(plat, where)
        return select_device(rig, spec, manipulator)
    raise DeviceError(
        f"rig: expected a SimRigSpec or HardwareRigSpec (formats.rig_file.load_rig), "
        f"got {type(spec).__name__}"
    )
