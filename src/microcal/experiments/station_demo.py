"""The demo of a whole station (preset ``thesis-platform``): every device in one {G}, and the
meet test of the two manipulators.

The cameras are calibrated once; each device (``m1``, ``m2``, the positioner ``p1``) is then
acquired, measured, identified and evaluated as :func:`~microcal.experiments.demo.run_demo`
does for one, in that one frame; last, the two manipulators' tips are sent to the same
points (ISO 9283's cube in the space both reach), open loop and closed, and the gap between
them measured by vision and by ground truth (:mod:`~microcal.procedures.meet`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ..devices.rig import platform_rig
from ..errors import InputError
from ..procedures.meet import MeetResult, meet_targets_um, meet_test
from ..procedures.station import Station
from ..sim import SimPlatform
from ..vision.stereo_calibration import StereoCalibration
from .demo import DemoResult, device_workspace, run_demo

__all__ = ["StationDemoResult", "run_station_demo"]


@dataclass
class StationDemoResult:
    """Each device's demo result, by name, and the meet tests by mode."""

    devices: dict[str, DemoResult] = field(default_factory=dict)
    meet: dict[str, MeetResult] = field(default_factory=dict)
    sim_time_s: float = 0.0


def run_station_demo(
    plat: SimPlatform,
    *,
    seed: int = 0,
    meet_cycles: int = 2,
    meet_modes: tuple[str, ...] = ("open", "closed"),
    progress: Callable[[str, int, int], None] | None = None,
    store_for: Callable[[str], Any] | None = None,
    **demo_options: Any,
) -> StationDemoResult:
    """Calibrate every device of ``plat`` in one {G}, then run the meet test.

    Parameters
    ----------
    plat : SimPlatform
        A platform with two manipulators ``m1`` and ``m2`` (and any further devices).
    meet_cycles : int
        Visits of the five meet targets per mode.
    meet_modes : tuple of {"open", "closed"}
        The loops the meet test runs in.
    store_for : callable (device name) -> store, optional
        The store of each device's acquired poses (see ``run_demo``).
    demo_options
        ``run_demo``'s keywords (poses, frames_per_pose, cycles, ...).

    Raises
    ------
    InputError
        A platform without the two manipulators.
    """
    names = list(plat.manipulators)
    if "m1" not in names or "m2" not in names:
        raise InputError(
            f"station demo: expected a platform with manipulators m1 and m2 (preset "
            f"thesis-platform), got {names}"
        )
    out = StationDemoResult()
    cameras: StereoCalibration | None = None
    for name in names:

        def tick(stage: str, done: int, total: int, name: str = name) -> None:
            if progress:
                progress(f"{name}: {stage}", done, total)

        result = run_demo(
            seed=seed, plat=plat, device=name, cameras=cameras, progress=tick,
            store=None if store_for is None else store_for(name), **demo_options,
        )  # fmt: skip
        cameras = result.calibration
        out.devices[name] = result
    rig = platform_rig(plat, "simulated, preset thesis-platform")
    models = out.devices["m1"].calibration.models()
    first = Station(rig.select("m1"), _entry(out, "m1"), models, frames=5, settle_s=5.0)
    second = Station(rig.select("m2"), _entry(out, "m2"), models, frames=5, settle_s=5.0)
    targets = meet_targets_um(
        first.calibration, second.calibration,
        device_workspace(plat.manipulators["m1"].limits_um),
        device_workspace(plat.manipulators["m2"].limits_um),
    )  # fmt: skip
    for mode in meet_modes:
        total = meet_cycles * len(targets)

        def meet_tick(done: int, _n: int, mode: str = mode, total: int = total) -> None:
            if progress:
                progress(f"meet test, {mode} loop", done, total)

        out.meet[mode] = meet_test(
            first, second, [t for _ in range(meet_cycles) for t in targets],
            mode="open" if mode == "open" else "closed", progress=meet_tick,
        )  # fmt: skip
    out.sim_time_s = plat.clock.now_s()
    return out


def _entry(result: StationDemoResult, name: str) -> Any:
    entry = result.devices[name].manipulator
    if entry is None:
        raise InputError(f"station demo: {name} was not identified")
    return entry
