"""The digital twin's rig file: the TOML text ``microcal twin --rig-out`` writes.

:func:`twin_rig_toml` renders a twin's description (:class:`~microcal.sim.twin_rig.TwinRig`)
as a hardware rig file that :func:`~microcal.formats.rig_file.load_rig` reads
(``examples/rigs/twin.toml`` is the one for the default ports); its first line is
:data:`RIG_HEADER`, by which microcal knows a twin rig file of its own.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

from ..devices.smaract_mcs2 import MCS2_PORT
from ..devices.twin_protocol import FRAMES_PORT
from ..sim.twin_rig import TwinRig

__all__ = ["RIG_HEADER", "twin_rig_toml"]

#: The first line of every rig file :func:`twin_rig_toml` writes (how microcal knows its own).
RIG_HEADER = "# The digital twin's rig, written by microcal twin."

Limits = Sequence[tuple[float, float]]  # per axis x, y, z: (low, high), µm


def _toml_limits(limits_um: Limits) -> str:
    """The soft limits of the axes that move (a held axis, low == high, is left out)."""
    pairs = ", ".join(
        f"{axis} = [{float(lo)!r}, {float(hi)!r}]"
        for axis, (lo, hi) in zip("xyz", limits_um, strict=True)
        if hi > lo
    )
    return "{ " + pairs + " }"


def _toml_channels(first: int, limits_um: Limits) -> str:
    """Channels ``first``, ``first + 1``, ``first + 2`` for x, y, z; an X-Y positioner (z
    held) names x and y alone, as its rig file on hardware would."""
    pairs = ", ".join(
        f"{axis} = {first + k}"
        for k, (axis, (lo, hi)) in enumerate(zip("xyz", limits_um, strict=True))
        if hi > lo
    )
    return "{ " + pairs + " }"


def _served(rig: TwinRig) -> list[str]:
    """What the twin serves through which protocol (the file's first comment)."""
    if rig.microscope is not None:
        return [
            "# The simulated microscope served through the real device protocols: the manipulator",
            "# through the SmarAct MCS2 driver, the camera, the X-Y stage and the focus through",
            "# Micro-Manager.",
        ]
    return [
        "# The simulated platform served through the real device protocols: the manipulator and",
        "# the target stage through the SmarAct MCS2 driver, the cameras through Micro-Manager.",
    ]


def _targets(rig: TwinRig) -> list[str]:
    """The rig's board (or tool tip) and its calibration target, with what they are."""
    if rig.calibration_target is None:
        return ["# the tool's tip the camera sees", f"board = {json.dumps(rig.board)}"]
    return [
        "# the chessboard on the end-effector, and the target on the target stage (the cameras",
        "# see the target while the stage was moved more recently than the manipulator)",
        f"board = {json.dumps(rig.board)}",
        f"calibration_target = {json.dumps(rig.calibration_target)}",
    ]


def twin_rig_toml(rig: TwinRig, rig_path: str = "twin.toml") -> str:
    """The hardware rig file that drives the twin ``rig`` describes through the real drivers.

    The manipulator and the target stage are SmarAct MCS2 channels 0-2 and 3-5 at
    ``host:mcs2_port``, further devices (``[manipulators.NAME]``) the channels after, each
    with its simulated device's limits; the cameras are Micro-Manager devices of
    :mod:`microcal.devices.twin_camera` fed by the frame server at ``host:frames_port``, with
    the simulated cameras' pixel sizes; a microscope's X-Y stage and focus (the ``patch``
    preset's) are the ``[microscope]``, Micro-Manager stages of
    :mod:`microcal.devices.twin_stages` on the same frame server. The comments say how to
    start the twin (``preset``, ``time_scale``) and check the rig (``rig_path``).

    Parameters
    ----------
    rig : TwinRig
        The twin (``Twin.rig_description()``, or ``microcal.sim.twin_rig.twin_rig`` of a
        platform).
    rig_path : str
        Where the file is saved (named in its comments).

    Returns
    -------
    str
        TOML text (:func:`~microcal.formats.rig_file.load_rig` reads it), starting with
        :data:`RIG_HEADER`.
    """
    host, mcs2_port, frames_port = rig.host, rig.mcs2_port, rig.frames_port
    preset, time_scale = rig.preset, rig.time_scale
    start = "microcal twin" + (f" --preset {preset}" if preset != "thesis" else "")
    start += f" --seed {rig.seed}"
    if host != "127.0.0.1":
        start += f" --host {host}"
    if mcs2_port != MCS2_PORT:
        start += f" --port {mcs2_port}"
    if frames_port != FRAMES_PORT:
        start += f" --frames-port {frames_port}"
    if time_scale != 1.0:
        start += f" --time-scale {time_scale:g}"
    address = json.dumps(host)
    faster = ["# (--time-scale 10: simulated time runs ten times faster than the wall clock)"]
    faster = faster if time_scale == 1.0 else []
    lines = [
        RIG_HEADER,
        *_served(rig),
        "# Start the twin first, in another terminal (it runs until Ctrl-C):",
        f"#   {start}",
        *faster,
        "# then use this rig like any other, e.g. check it without moving anything:",
        f"#   microcal acquire --rig {rig_path} --out runs/a --dry-run",
        "# Needs: pip install 'microcal[mm]'  (see docs/hardware.md, 'The digital twin')",
        'driver = "hardware"',
        *_targets(rig),
        "",
        "[manipulator]",
        'kind = "smaract-mcs2"',
        "# the twin's MCS2 peer: channels 0-2 move the manipulator"
        + (", 3-5 the target stage" if rig.target_stage is not None else ""),
        f"address = {address}",
        f"port = {mcs2_port}",
        "channels = { x = 0, y = 1, z = 2 }",
        "# soft limits, µm: the simulated manipulator's travel",
        f"limits_um = {_toml_limits(rig.manipulator.limits_um)}",
    ]
    if rig.target_stage is not None:
        lines += [
            "",
            "[target_stage]",
            "# the stage carrying the calibration target (stereo-calibrate --rig moves it)",
            'kind = "smaract-mcs2"',
            f"address = {address}",
            f"port = {mcs2_port}",
            "channels = { x = 3, y = 4, z = 5 }",
            f"limits_um = {_toml_limits(rig.target_stage.limits_um)}",
        ]
    for device in rig.further:
        name, c = device.name, device.first_channel
        lines += [
            "",
            f"[manipulators.{name}]",
            f"# the twin's further device {name}: channels {c}-{c + 2}",
            'kind = "smaract-mcs2"',
            f"address = {address}",
            f"port = {mcs2_port}",
            f"channels = {_toml_channels(c, device.limits_um)}",
            f"limits_um = {_toml_limits(device.limits_um)}",
        ]
    if rig.microscope is not None:
        scope = rig.microscope
        lines += [
            "",
            "[microscope]",
            "# the microscope's X-Y stage and focus drive: Micro-Manager devices of the twin",
            f"xy_stage = {json.dumps(scope.xy_stage)}",
            f"focus = {json.dumps(scope.focus)}",
            f"limits_um = {_toml_limits(scope.limits_um)}",
        ]
    lines += [
        "",
        "[micromanager]",
        "# pure-Python devices served by the twin: its camera and the microscope's stages"
        if rig.microscope is not None
        else "# pure-Python devices: one camera per simulated camera, frames from the twin",
        'python_devices = "microcal.devices.twin_camera:load"',
        f"options = {{ address = {address}, port = {frames_port}{_timeout(rig)} }}",
    ]
    for cam in rig.cameras:
        lines += [
            "",
            f"[cameras.{cam.name}]",
            'kind = "micromanager"',
            f"device = {json.dumps(cam.name)}",
            f"pixel_size_um = {cam.pixel_size_um!r}",
        ]
    return "\n".join(lines) + "\n"


def _timeout(rig: TwinRig) -> str:
    """The one-camera rig's frames wait longer: a whole 2048 x 2048 frame takes seconds."""
    return ", timeout_s = 60.0" if rig.microscope is not None else ""
