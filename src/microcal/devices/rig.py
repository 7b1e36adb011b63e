"""Open the devices a rig file names: the simulator, or hardware drivers.

``open_rig(load_rig("myrig.toml"))`` gives a :class:`Rig` whose manipulator, cameras and clock
the procedures drive the same way whatever is behind them. Close it when done (it is a
context manager).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import DeviceError
from ..vision.targets import Target, parse_target
from .base import Camera, Clock, Manipulator, RealClock

__all__ = ["Rig", "open_rig"]


@dataclass
class Rig:
    """The opened devices of a rig."""

    manipulator: Manipulator
    cameras: dict[str, Camera]
    clock: Clock
    board: Target
    temperature: Callable[[], float] | None = None
    description: dict[str, str] = field(default_factory=dict)  # device -> what answered
    _closers: list[Callable[[], None]] = field(default_factory=list)

    def close(self) -> None:
        """Release every device (errors while closing are ignored)."""
        for close in reversed(self._closers):
            with contextlib.suppress(Exception):
                close()
        self._closers.clear()

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def _sim(spec: dict[str, Any]) -> Rig:
    from ..sim import platform

    plat = platform(spec["preset"], seed=spec["seed"], overrides=spec["overrides"])
    return Rig(
        plat.manipulator,
        dict(plat.cameras),
        plat.clock,
        plat.scene.board,
        temperature=lambda: plat.manipulator.temperature_at(plat.clock.now_s()),
        description={"platform": f"simulated, preset {spec['preset']}, seed {spec['seed']}"},
    )


def _hardware(spec: dict[str, Any]) -> Rig:
    closers: list[Callable[[], None]] = []
    try:
        return _open_hardware(spec, closers)
    except BaseException:
        for close in reversed(closers):
            with contextlib.suppress(Exception):
                close()
        raise


def _open_hardware(spec: dict[str, Any], closers: list[Callable[[], None]]) -> Rig:
    m = spec["manipulator"]
    description: dict[str, str] = {}
    core: Any = None
    if "micromanager" in spec:
        from .micromanager import open_core

        mm = spec["micromanager"]
        core = open_core(mm.get("config"), mm.get("python_devices"))
        closers.append(core.unloadAllDevices)
    manipulator: Manipulator
    if m["kind"] == "smaract-mcs2":
        from .smaract_mcs2 import MCS2Manipulator

        axes = list(m["channels"])
        limits = np.array([m["limits_um"][a] for a in axes], dtype=np.float64)
        mcs2 = MCS2Manipulator(
            m["address"],
            m["channels"],
            limits,
            port=m.get("port", 55551),
            timeout_s=m.get("timeout_s", 2.0),
            reconnects=m.get("reconnects", 2),
            speed_um_s=m.get("speed_um_s"),
        )
        mcs2.connect()
        closers.append(mcs2.close)
        description["manipulator"] = f"SmarAct MCS2 {mcs2.serial} at {m['address']}"
        manipulator = mcs2
    else:
        from .micromanager import MMManipulator

        limits = np.array([m["limits_um"][a] for a in "xyz"], dtype=np.float64)
        manipulator = MMManipulator(
            core, xy_stage=m["xy_stage"], focus=m["focus"], limits_um=limits
        )
        description["manipulator"] = f"Micro-Manager {m['xy_stage']} + {m['focus']}"
    cameras: dict[str, Camera] = {}
    for name, c in spec["cameras"].items():
        exposure_s = c["exposure_ms"] / 1e3 if "exposure_ms" in c else None
        if c["kind"] == "aravis":
            from .aravis_camera import AravisCamera

            region = c.get("region_px")
            cam = AravisCamera(
                c["address"],
                name=name,
                exposure_s=exposure_s or 0.01,
                pixel_format=c.get("pixel_format", "Mono8"),
                region_px=tuple(region) if region else None,
                timeout_s=c.get("timeout_s", 2.0),
                pixel_size_um=c.get("pixel_size_um", 3.45),
            )
            closers.append(cam.close)
            description[name] = f"{cam.vendor} {cam.serial} at {c['address']}"
            cameras[name] = cam
        else:
            from .micromanager import MMCamera

            cameras[name] = MMCamera(core, c["device"], name=name, exposure_s=exposure_s)
            description[name] = f"Micro-Manager camera {c['device']}"
    return Rig(
        manipulator,
        cameras,
        RealClock(),
        parse_target(spec.get("board", "chessboard:4x3:400")),
        description=description,
        _closers=closers,
    )


def open_rig(spec: dict[str, Any]) -> Rig:
    """Open the devices of a rig (``formats.rig_file.load_rig``'s result).

    Raises
    ------
    DeviceError
        A device that cannot be reached or set up; the message names it.
    """
    if spec["driver"] == "sim":
        return _sim(spec)
    if spec["driver"] == "hardware":
        return _hardware(spec)
    raise DeviceError(f"rig: driver {spec['driver']!r} is unknown")
