"""Opening a calibrated rig from its files: ``microcal.open_station(rig, calibration)``.

``goto``, ``evaluate`` and ``check`` open their rig and calibration here, in one way.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from ..devices.rig import Rig
from ..devices.rig_spec import RigSpec
from ..errors import InputError
from ..formats.calibration_file import load_calibration
from ..formats.rig_file import load_rig
from ..geometry import AnyCamera
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..procedures.one_camera_probe import OneCameraTipProbe
from ..procedures.station import Station
from .calibration_update import camera_models
from .one_camera_station import is_one_camera, one_camera_device
from .options import rig_with_seed
from .rigs import open_rig

__all__ = ["CalibratedRig", "goto_target", "open_calibrated_rig", "open_station"]


@dataclass(frozen=True)
class CalibratedRig:
    """An opened rig with the calibration of one of its devices.

    Attributes
    ----------
    spec : RigSpec
        The rig as its file (or ``sim``) named it, with the seed applied.
    opened : Rig
        The opened rig (close it, or use it as a context manager).
    device : Rig
        ``opened`` with the calibrated device selected (``Rig.for_calibration``).
    entry : ManipulatorCalibration
        The device's calibration.
    models : dict of str -> camera model
        The calibration's cameras.
    probe : OneCameraTipProbe, optional
        On a one-camera rig, what measures the tip (``device`` then holds the device with
        its joints as the calibration counts them; :mod:`~.one_camera_station`).
    """

    spec: RigSpec
    opened: Rig
    device: Rig
    entry: ManipulatorCalibration
    models: dict[str, AnyCamera]
    probe: OneCameraTipProbe | None = None


def open_calibrated_rig(
    rig: str | os.PathLike[str] = "sim",
    calibration: str | os.PathLike[str] = "calibration.json",
    *,
    manipulator: str | None = None,
    seed: int | None = None,
    scope: str | os.PathLike[str] | None = None,
    objective: str | None = None,
    one_camera_refused: str | None = None,
) -> CalibratedRig:
    """Load the calibration (with its cameras), then open the rig and select its device.

    A one-camera rig (one camera and a microscope's focus) measures the tip through the
    scope calibration ``scope`` (its set ``objective``; :mod:`~.one_camera_station`), or,
    for a caller that does not serve one, is refused with ``one_camera_refused``.

    Raises
    ------
    InputError, FormatError, DeviceError
        A calibration or rig file that cannot be read, a device it does not name, a device
        that cannot be opened, a one-camera rig without its scope file or a scope file for
        a rig of several cameras; one line each. Nothing is left open.
    """
    cal = load_calibration(calibration)
    m = cal.manipulator(manipulator)
    models = camera_models(cal) if cal.cameras else {}  # a one-camera rig's has none
    spec = rig_with_seed(load_rig(str(rig)), seed)
    opened = open_rig(spec)
    try:
        device = opened.for_calibration(m.name)
        if not is_one_camera(device):
            if scope is not None:
                raise InputError(
                    f"--scope: the rig has {len(device.cameras)} cameras and no microscope "
                    "focus; a scope calibration serves a one-camera rig (leave --scope out)"
                )
            models = models or camera_models(cal)  # refused: no cameras to measure with
            return CalibratedRig(spec, opened, device, m, models)
        if one_camera_refused is not None:
            raise InputError(one_camera_refused)
        one = one_camera_device(device, m, scope, objective)
        return CalibratedRig(spec, opened, one.rig, m, models, one.probe)
    except BaseException:
        opened.close()
        raise


def open_station(
    rig: str | os.PathLike[str] = "sim",
    calibration: str | os.PathLike[str] = "calibration.json",
    *,
    manipulator: str | None = None,
    seed: int | None = None,
    scope: str | os.PathLike[str] | None = None,
    objective: str | None = None,
    **options: Any,
) -> Station:
    """Open the rig and load the calibration (with its cameras) into a :class:`Station`.

    Parameters
    ----------
    rig : str or path
        ``"sim"`` (the simulated thesis platform) or a rig file.
    calibration : str or path
        calibration.json with the cameras (``microcal fit --cameras``).
    manipulator : str, optional
        Which manipulator of the calibration (optional when it holds one).
    seed : int, optional
        The simulated rig's seed.
    scope, objective : optional
        A one-camera rig's scope calibration and its objective's set.
    options
        :class:`Station`'s keywords (``frames``, ``settle_s``, ``servo``).

    Example
    -------
    >>> with microcal.open_station("sim", "demo-out/calibration.json") as station:  # doctest: +SKIP
    ...     arrival = station.move_to_um([3000.0, 2000.0, 1500.0], mode="closed")
    """
    c = open_calibrated_rig(rig, calibration, manipulator=manipulator, seed=seed, scope=scope,
                            objective=objective)  # fmt: skip
    try:
        if c.probe is not None:
            options = {"probe": c.probe, **options}
        return Station(c.device, c.entry, c.models, **options)
    except BaseException:
        c.opened.close()
        raise


def goto_target(
    xyz_um: tuple[float | None, float | None, float | None], along_approach_um: float | None
) -> list[float] | None:
    """``goto``'s target: X Y Z (all three), or None for a move along the approach axis
    (``--along-approach-um``, then no X Y Z).

    Raises
    ------
    InputError
        Some of X Y Z but not all, both forms, or neither; one line.
    """
    given = [v for v in xyz_um if v is not None]
    if along_approach_um is not None:
        if given:
            raise InputError("goto: give X Y Z or --along-approach-um D, not both")
        return None
    if len(given) != 3:
        raise InputError(
            f"goto: expected the target X Y Z in µm (got {len(given)} of them), or "
            "--along-approach-um D"
        )
    return [float(v) for v in given]
