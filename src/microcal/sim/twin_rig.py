"""What the digital twin's rig file says, as data: where the twin listens and what it serves.

:func:`twin_rig` describes a simulated platform served by a twin (:meth:`Twin.rig_description
<microcal.sim.twin.Twin.rig_description>`: the twin as started);
``microcal.formats.twin_rig_file.twin_rig_toml`` writes the description as a rig file.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..devices.smaract_mcs2 import MCS2_PORT
from ..devices.twin_protocol import FRAMES_PORT
from .mcs2_peer import mcs2_devices
from .platforms import SimPlatform

__all__ = ["TwinRig", "TwinRigCamera", "TwinRigDevice", "TwinRigMicroscope", "twin_rig"]


@dataclass(frozen=True)
class TwinRigDevice:
    """One device on the twin's MCS2 peer.

    Attributes
    ----------
    name : str
        ``m1`` (the manipulator), ``target_stage``, or a further device's name (``m2``, ...).
    first_channel : int
        Its x channel; y and z are the next two.
    limits_um : ((lo, hi), (lo, hi), (lo, hi)) float
        The simulated device's travel per axis x, y, z, µm (lo == hi: an axis held).
    """

    name: str
    first_channel: int
    limits_um: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class TwinRigCamera:
    """One camera of the twin's frame server: its name and pixel size, µm."""

    name: str
    pixel_size_um: float


@dataclass(frozen=True)
class TwinRigMicroscope:
    """The microscope's X-Y stage and focus drive of the twin's frame server (the ``patch``
    preset's): their Micro-Manager labels and travel per axis x, y, z, µm."""

    xy_stage: str
    focus: str
    limits_um: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class TwinRig:
    """The twin as a rig file describes it (how to start it, and every device's entry).

    Attributes
    ----------
    preset : str
    seed : int
        The simulated platform's.
    host : str
        The loopback address the twin listens on.
    mcs2_port, frames_port : int
        The MCS2 peer's and the frame server's ports.
    time_scale : float
        Simulated seconds per wall second.
    board : str
        The end-effector's board (or the tool's tip).
    calibration_target : str or None
        The target stage's calibration target (None: no target stage).
    manipulator : TwinRigDevice
        Channels 0-2.
    target_stage : TwinRigDevice or None
        Channels 3-5, if the platform has a target stage.
    further : tuple of TwinRigDevice
        The further devices (``[manipulators.NAME]``), on the channels after.
    cameras : tuple of TwinRigCamera
    microscope : TwinRigMicroscope or None
        The microscope's stage and focus (the ``patch`` preset's), served as Micro-Manager
        devices.
    """

    preset: str
    seed: int
    host: str
    mcs2_port: int
    frames_port: int
    time_scale: float
    board: str
    calibration_target: str | None
    manipulator: TwinRigDevice
    target_stage: TwinRigDevice | None
    further: tuple[TwinRigDevice, ...]
    cameras: tuple[TwinRigCamera, ...]
    microscope: TwinRigMicroscope | None = None


def twin_rig(
    plat: SimPlatform,
    *,
    host: str = "127.0.0.1",
    mcs2_port: int = MCS2_PORT,
    frames_port: int = FRAMES_PORT,
    preset: str = "thesis",
    time_scale: float = 1.0,
) -> TwinRig:
    """The rig of a twin serving ``plat`` at ``host`` on the given ports.

    The devices take the MCS2 peer's channels in its order (:func:`~microcal.sim.mcs2_peer.
    mcs2_devices`), three each, with their simulated limits; the cameras their simulated
    pixel sizes. ``preset`` and ``time_scale`` say how the twin was started.
    """
    devices = [
        TwinRigDevice(name, 3 * k, tuple((float(lo), float(hi)) for lo, hi in d.limits_um))
        for k, (name, d) in enumerate(mcs2_devices(plat))
    ]
    stage = devices[1] if plat.target_stage is not None else None
    return TwinRig(
        preset=preset,
        seed=plat.seed,
        host=host,
        mcs2_port=mcs2_port,
        frames_port=frames_port,
        time_scale=time_scale,
        board=plat.config.board,
        calibration_target=plat.config.calibration_target,
        manipulator=devices[0],
        target_stage=stage,
        further=tuple(devices[2 if stage is not None else 1 :]),
        cameras=tuple(TwinRigCamera(n, c.pixel_size_um) for n, c in plat.cameras.items()),
    )
