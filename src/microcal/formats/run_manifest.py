"""run.json's manifest, built in one place for ``acquire`` and the demo."""

from __future__ import annotations

from typing import Any

from .provenance import provenance

__all__ = ["new_manifest"]


def new_manifest(
    *,
    rig: dict[str, Any],
    target: str,
    cameras: list[str],
    design: dict[str, object],
    settle: str,
    frames_per_pose: int,
    store: str,
    command: str,
    device: str = "",
    manipulator: str = "m1",
    held_joints_um: dict[str, float] | None = None,
    **provenance_extra: Any,
) -> dict[str, Any]:
    """The manifest of a new run: every option that shapes it, and where it came from.

    Parameters
    ----------
    rig : dict
        The rig as recorded (its spec; a resume must name the same).
    design : dict
        ``{"kind", "poses", "seed", "low_um", "high_um"}``: enough to draw the same commands
        again (``make_design(kind, poses, low_um, high_um, seed)``).
    settle : str
        ``vision`` or ``fixed:SECONDS``.
    store : str
        ``full`` frames or ``roi``.
    device : str
        The manipulator's identity (``Manipulator.identity``; left out when empty).
    manipulator : str
        The rig's device the run moves (left out when ``m1``, the only one of most rigs).
    held_joints_um : dict of str -> float, optional
        Joints the device holds still (an X-Y positioner's ``dz``) and their value; ``fit``
        leaves them out of the model (left out when none).
    """
    return (
        {
            "rig": rig,
            "target": target,
            "cameras": list(cameras),
            "design": design,
            "settle": settle,
            "frames_per_pose": frames_per_pose,
            "store": store,
            "provenance": provenance(command=command, **provenance_extra),
        }
        | ({"device": device} if device else {})
        | ({"manipulator": manipulator} if manipulator != "m1" else {})
        | ({"held_joints_um": dict(held_joints_um)} if held_joints_um else {})
    )
