"""Opening a calibrated rig from its files: ``microcal.open_station(rig, calibration)``.

``goto``, ``evaluate`` and ``check`` open their rig and calibration here, in one way.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

from ..devices.rig import Rig
from ..devices.rig_spec import RigSpec
from ..formats.calibration_file import load_calibration
from ..formats.rig_file import load_rig
from ..geometry import AnyCamera
from ..kinematics.manipulator_calibration import ManipulatorCalibration
from ..procedures.station import Station
from .calibration_update import camera_models
from .options import rig_with_seed
from .rigs import open_rig

__all__ = ["CalibratedRig", "open_calibrated_rig", "open_station"]


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
    """

    spec: RigSpec
    opened: Rig
    device: Rig
    entry: ManipulatorCalibration
    models: dict[str, AnyCamera]


def open_calibrated_rig(
    rig: str | os.PathLike[str] = "sim",
    calibration: str | os.PathLike[str] = "calibration.json",
    *,
    manipulator: str | None = None,
    seed: int | None = None,
) -> CalibratedRig:
    """Load the calibration (with its cameras), then open the rig and select its device.

    Raises
    ------
    InputError, FormatError, DeviceError
        A calibration or rig file that cannot be read, a device it does not name, a device
        that cannot be opened; one line each. Nothing is left open.
    """
    cal = load_calibration(calibration)
    m, models = cal.manipulator(manipulator), camera_models(cal)
    spec = rig_with_seed(load_rig(str(rig)), seed)
    opened = open_rig(spec)
    try:
        return CalibratedRig(spec, opened, opened.for_calibration(m.name), m, models)
    except BaseException:
        opened.close()
        raise


def open_station(
    rig: str | os.PathLike[str] = "sim",
    calibration: str | os.PathLike[str] = "calibration.json",
    *,
    manipulator: str | None = None,
    seed: int | None = None,
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
    options
        :class:`Station`'s keywords (``frames``, ``settle_s``, ``servo``).

    Example
    -------
    >>> with microcal.open_station("sim", "demo-out/calibration.json") as station:  # doctest: +SKIP
    ...     arrival = station.move_to_um([3000.0, 2000.0, 1500.0], mode="closed")
    """
    c = open_calibrated_rig(rig, calibration, manipulator=manipulator, seed=seed)
    try:
        return Station(c.device, c.entry, c.models, **options)
    except BaseException:
        c.opened.close()
        raise
