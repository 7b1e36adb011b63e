"""Opening a calibrated station from its files: ``microcal.open_station(rig, calibration)``."""

from __future__ import annotations

import os
from typing import Any

from ..devices.rig import open_rig
from ..procedures.station import Station
from .calibration_file import load_calibration
from .calibration_update import camera_models
from .options import rig_with_seed
from .rig_file import load_rig

__all__ = ["open_station"]


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
    cal = load_calibration(calibration)
    m, models = cal.manipulator(manipulator), camera_models(cal)
    opened = open_rig(rig_with_seed(load_rig(str(rig)), seed))
    try:
        return Station(opened.for_calibration(m.name), m, models, **options)
    except BaseException:
        opened.close()
        raise
