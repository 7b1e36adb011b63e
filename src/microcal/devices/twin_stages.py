"""The digital twin's microscope stages as Micro-Manager devices (pymmcore-plus ``unicore``).

The twin of the ``patch`` preset serves its focus drive and X-Y stage on the frame server
(``MOVE``, ``POS``, ``BUSY``, ``STOP``: :mod:`microcal.devices.twin_protocol`). The twin's
loader (:func:`microcal.devices.twin_camera.load`) loads one :class:`TwinXYStage` and one
:class:`TwinFocus` per stage the twin lists, labelled with the stage's name (``XYStage``,
``Focus``), beside its cameras and on their connection; a rig file's ``[microscope]`` names
them (``xy_stage = "XYStage"``, ``focus = "Focus"``), and
``devices.micromanager.MMManipulator`` drives them as joints x, y, z as it drives a real
microscope's.

Each call is one request: a move is sent as it is (the twin refuses a position outside the
stage's travel: :class:`~microcal.errors.LimitError`, one line, nothing moved); a position is
the twin's readout; ``busy`` is true while the stage moves (a focus move is answered once
it has settled). Neither stage has an origin of its own to set (:class:`DeviceError`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

from pymmcore_plus.experimental.unicore import StageDevice, XYStageDevice

from .._validation import excerpt
from ..errors import DeviceError
from .twin_protocol import BUSY, MOVE, POS, STOP, StageInfo, info_stage

__all__ = ["StageClient", "TwinFocus", "TwinXYStage", "load_stages"]


class StageClient(Protocol):
    """The connection to the twin's frame server the stages send their requests on (the
    cameras' ``devices.twin_camera.FrameClient``)."""

    address: str
    port: int

    def stage(self, request: str, count: int) -> tuple[float, ...]:
        """Send a stage request; the ``count`` numbers of its ``OK`` answer (LimitError for
        a position outside the stage's travel, DeviceError for any other refusal)."""
        ...


class _TwinStage:
    """The requests of one of the twin's stages."""

    def __init__(self, client: StageClient, info: StageInfo) -> None:
        self._client, self.info = client, info

    def _move(self, *values_um: float) -> None:
        words = " ".join(repr(float(v)) for v in values_um)
        self._client.stage(f"{MOVE} {self.info.name} {words}", 0)

    def _position(self, count: int) -> tuple[float, ...]:
        return self._client.stage(f"{POS} {self.info.name}", count)

    def _busy(self) -> bool:
        return self._client.stage(f"{BUSY} {self.info.name}", 1)[0] != 0.0

    def _stop(self) -> None:
        self._client.stage(f"{STOP} {self.info.name}", 0)

    def _no_origin(self) -> None:
        raise DeviceError(f"twin: stage {self.info.name} has no origin to set (its home is 0)")


class TwinXYStage(XYStageDevice):  # type: ignore[misc, unused-ignore]  # Any without stubs
    """The twin's X-Y stage as a pure-Python Micro-Manager XY stage, µm."""

    def __init__(self, client: StageClient, info: StageInfo) -> None:
        super().__init__()
        self._stage = _TwinStage(client, info)

    def set_position_um(self, x: float, y: float) -> None:
        """Move to (x, y) µm (LimitError outside the travel)."""
        self._stage._move(x, y)

    def get_position_um(self) -> tuple[float, float]:
        """The readout, (x, y) µm."""
        x, y = self._stage._position(2)
        return x, y

    def busy(self) -> bool:
        """True while the stage moves."""
        return self._stage._busy()

    def stop(self) -> None:
        """Stop where it is."""
        self._stage._stop()

    def home(self) -> None:
        """Move to (0, 0)."""
        self._stage._move(0.0, 0.0)

    def set_origin_x(self) -> None:
        self._stage._no_origin()

    def set_origin_y(self) -> None:
        self._stage._no_origin()


class TwinFocus(StageDevice):  # type: ignore[misc, unused-ignore]  # Any without stubs
    """The twin's focus drive as a pure-Python Micro-Manager stage, µm from its home."""

    def __init__(self, client: StageClient, info: StageInfo) -> None:
        super().__init__()
        self._stage = _TwinStage(client, info)

    def set_position_um(self, val: float) -> None:
        """Move to ``val`` µm (from below; LimitError outside the drive's range)."""
        self._stage._move(val)

    def get_position_um(self) -> float:
        """The drive's readout, µm."""
        return self._stage._position(1)[0]

    def busy(self) -> bool:
        """True while it moves (a move is answered once it has settled)."""
        return self._stage._busy()

    def stop(self) -> None:
        """Stop where it is."""
        self._stage._stop()

    def home(self) -> None:
        """Move to 0."""
        self._stage._move(0.0)

    def set_origin(self) -> None:
        self._stage._no_origin()


def load_stages(core: Any, client: StageClient, stages: Sequence[Mapping[str, Any]]) -> None:
    """Load the stages of the twin's INFO answer into a ``UniMMCore``, by their names.

    Raises
    ------
    DeviceError
        A stage described as no stage of the protocol (its kind or travel).
    """
    for stage in stages:
        try:
            info = info_stage(stage)
        except (KeyError, TypeError, ValueError):
            raise DeviceError(
                f"twin at {client.address}:{client.port}: a stage described as {excerpt(stage)}"
            ) from None
        device = TwinXYStage(client, info) if info.kind == "xy" else TwinFocus(client, info)
        core.loadPyDevice(info.name, device)
