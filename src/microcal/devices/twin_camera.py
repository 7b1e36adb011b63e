"""The digital twin's cameras as Micro-Manager devices (pymmcore-plus ``unicore``).

A rig file's ``[micromanager]`` table names ``python_devices =
"microcal.devices.twin_camera:load"`` with ``options = {address = ..., port = ...}``: the
Micro-Manager bridge then calls :func:`load`, which asks the twin's frame server
(:mod:`microcal.sim.frame_server`) for its cameras and loads one :class:`TwinCamera` per
camera, labelled with the camera's name. Each snap fetches one frame (``GRAB <camera>``), so
the frames reach microcal through ``devices.micromanager.MMCamera`` as a real camera's would.
A camera also gives frames read by region (:meth:`TwinCamera.grab_lazy`: ``SNAP``, then one
``REGION`` per region read, :class:`TwinFrame`), which ``MMCamera.grab_lazy`` hands on: a
procedure that looks at the tip's neighbourhood in a 2048 x 2048 frame moves its pixels, not
8 MB. Where the twin serves stages (the ``patch`` preset's focus and X-Y stage), :func:`load`
loads them too (:mod:`microcal.devices.twin_stages`), on the same connection.
The protocol, its words and limits are :mod:`microcal.devices.twin_protocol`'s.

A dropped frame is a :class:`FrameError` and a frame that does not come in time a
:class:`DeviceTimeoutError` (both transient: grab again); a twin that cannot be reached is a
one-line :class:`DeviceError` saying how to start it.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymmcore_plus.experimental.unicore import SimpleCameraDevice

from ..errors import DeviceError, DeviceTimeoutError, LimitError
from .twin_protocol import (
    DTYPES,
    EOL,
    FRAMES_PORT,
    GRAB,
    INFO,
    KIND_LIMIT,
    MAX_HEADER_BYTES,
    OK,
    REGION,
    SNAP,
    SnapHeader,
    decode_error,
    decode_frame,
    decode_info,
    error_of_kind,
    exposure_request,
    frame_size_problem,
    grab_request,
    info_camera,
    info_regions,
    parse_frame_header,
    parse_numbers,
    parse_snap_header,
    region_request,
    snap_request,
)
from .twin_stages import load_stages

__all__ = ["FRAMES_PORT", "FrameClient", "TwinCamera", "TwinFrame", "load"]


class _RefusedError(Exception):
    """An answer refused unread: its connection is dropped and the request not sent again."""


class FrameClient:
    """One connection to the twin's frame server, shared by its cameras (thread-safe).

    A connection that breaks is opened again once per request. Nothing the server says is
    trusted: an answer line longer than :data:`MAX_HEADER_BYTES` drops the connection, and a
    frame's header is checked before a byte of the frame is read
    (:func:`~microcal.devices.twin_protocol.parse_frame_header`: at most
    :data:`~microcal.devices.twin_protocol.MAX_FRAME_BYTES`, exactly height x width pixels of
    a known type), so no more memory is taken than the one frame the protocol allows.

    Parameters
    ----------
    address : str
        The twin's address (loopback).
    port : int
        The frame server's port.
    timeout_s : float
        Longest wait for one answer, s.
    """

    def __init__(self, address: str, port: int, timeout_s: float = 10.0) -> None:
        self.address, self.port, self.timeout_s = address, int(port), float(timeout_s)
        self._sock: socket.socket | None = None
        self._buffer = bytearray()
        self._lock = threading.Lock()

    def _where(self) -> str:
        return f"{self.address}:{self.port}"

    def _open(self) -> socket.socket:
        try:
            sock = socket.create_connection((self.address, self.port), self.timeout_s)
        except OSError as exc:
            raise DeviceError(
                f"no digital twin at {self._where()} ({exc.strerror or exc}); start it with "
                f"`microcal twin --frames-port {self.port}` in another terminal"
            ) from None
        sock.settimeout(self.timeout_s)
        return sock

    def close(self) -> None:
        """Close the connection (the next request opens it again)."""
        with self._lock:
            self._drop()

    def _drop(self) -> None:
        if self._sock is not None:
            self._sock.close()
        self._sock, self._buffer = None, bytearray()

    def _recv_into(self, view: memoryview, deadline: float) -> int:
        """Bytes received into ``view`` (at least one)."""
        assert self._sock is not None
        if time.monotonic() > deadline:
            raise TimeoutError
        n = self._sock.recv_into(view)
        if not n:
            raise ConnectionError("closed by the twin")
        return n

    def _read_line(self, deadline: float) -> bytes:
        """The next answer line, without its end (at most :data:`MAX_HEADER_BYTES`)."""
        chunk = bytearray(1 << 16)
        searched = 0
        while (end := self._buffer.find(b"\n", searched)) < 0:
            if len(self._buffer) > MAX_HEADER_BYTES:
                raise ConnectionError("an answer line too long: not a microcal twin")
            searched = len(self._buffer)
            n = self._recv_into(memoryview(chunk), deadline)
            self._buffer += chunk[:n]
        line = bytes(self._buffer[:end])
        del self._buffer[: end + 1]
        return line.rstrip(b"\r")

    def _read_exactly(self, n: int, deadline: float) -> bytearray:
        """The next ``n`` bytes (``n`` checked against the protocol's limit), in one buffer."""
        data = bytearray(n)
        have = min(n, len(self._buffer))
        data[:have] = self._buffer[:have]
        del self._buffer[:have]
        view = memoryview(data)
        while have < n:
            have += self._recv_into(view[have:], deadline)
        return data

    def _exchange(self, request: str) -> tuple[str, bytearray | None]:
        """Send one request; its answer line and, after a GRAB's checked header, the frame."""
        if self._sock is None:
            self._sock = self._open()
        self._sock.sendall(request.encode("ascii") + EOL)
        deadline = time.monotonic() + self.timeout_s
        line = self._read_line(deadline).decode("ascii", errors="replace")
        if not request.startswith((f"{GRAB} ", f"{REGION} ")):
            return line, None
        try:
            header = parse_frame_header(line)
        except ValueError as exc:
            raise _RefusedError(str(exc)) from None
        if header is None:
            return line, None
        return line, self._read_exactly(header.nbytes, deadline)

    def request(self, request: str) -> tuple[str, bytearray | None]:
        """Send one request and read its answer: the line, and a GRAB's frame bytes (None for
        any other answer).

        Raises
        ------
        DeviceError
            The twin cannot be reached, the connection broke twice, or the answer is refused
            unread (a frame above the protocol's limit, or not of its header's shape).
        DeviceTimeoutError
            No answer within ``timeout_s``.
        """
        with self._lock:
            for attempt in range(2):
                try:
                    return self._exchange(request)
                except TimeoutError:
                    self._drop()  # a late answer would pair with the next request
                    raise DeviceTimeoutError(
                        f"twin at {self._where()}: no answer to {request!r} within "
                        f"{self.timeout_s:g} s"
                    ) from None
                except _RefusedError as exc:
                    self._drop()  # the frame's bytes, unread, would pair with the next
                    raise DeviceError(
                        f"twin at {self._where()}: the answer to {request!r} {exc}; refused "
                        "unread (is this a microcal twin's frame server?)"
                    ) from None
                except (ConnectionError, OSError, ValueError) as exc:
                    self._drop()
                    if attempt == 1:
                        raise DeviceError(
                            f"twin at {self._where()}: connection lost ({exc}); is it still "
                            "running?"
                        ) from None
        raise AssertionError("unreachable")

    def info(self) -> dict[str, Any]:
        """The twin's INFO: its cameras (name, width, height, dtype, exposure_ms ...)."""
        line, _ = self.request(INFO)
        error = decode_error(line)
        if error is not None:  # busy, say
            raise error_of_kind(error[0])(f"twin at {self._where()}: {error[0]}: {error[1]}")
        try:
            return decode_info(line)
        except (ValueError, KeyError, TypeError):
            raise DeviceError(
                f"{self._where()} answered {line[:60]!r} to INFO: not a microcal twin's frame "
                "server (is the port the MCS2 one?)"
            ) from None

    def grab(self, camera: str) -> NDArray[np.unsignedinteger]:
        """One frame of a camera, (height, width), uint8 or uint16.

        Raises
        ------
        FrameError, DeviceTimeoutError
            The twin lost the frame or it came too late (grab again).
        DeviceError
            Any other failure.
        """
        line, data = self.request(grab_request(camera))
        header = parse_frame_header(line)  # checked already when the bytes were read
        if header is not None and data is not None:
            return decode_frame(header, data)
        error = decode_error(line)  # neither a frame nor an error: said below
        if error is not None:
            kind, message = error
            raise error_of_kind(kind)(message or line)
        raise DeviceError(f"twin at {self._where()}: unexpected answer {line[:60]!r} to {GRAB}")

    def snap(self, camera: str) -> TwinFrame:
        """One frame of a camera, kept by the twin and read by region (:class:`TwinFrame`).

        Raises
        ------
        FrameError, DeviceTimeoutError
            The twin lost the frame or it came too late (grab again).
        DeviceError
            Any other failure (an answer that is not a frame's, refused).
        """
        line, _ = self.request(snap_request(camera))
        try:
            header = parse_snap_header(line)
        except ValueError as exc:
            raise DeviceError(f"twin at {self._where()}: the answer to SNAP {exc}") from None
        if header is not None:
            return TwinFrame(self, header)
        error = decode_error(line)
        if error is not None:
            raise error_of_kind(error[0])(error[1] or line)
        raise DeviceError(f"twin at {self._where()}: unexpected answer {line[:60]!r} to {SNAP}")

    def region(self, header: SnapHeader, box: tuple[int, int, int, int]) -> NDArray[Any]:
        """The pixels of a kept frame over ``box`` (x0, y0, x1, y1, inside the frame).

        Raises
        ------
        DeviceError
            The twin no longer keeps the frame, or any other failure.
        """
        line, data = self.request(region_request(header.frame_id, box))
        frame_header = parse_frame_header(line)
        if frame_header is not None and data is not None:
            x0, y0, x1, y1 = box
            shape = (y1 - y0, x1 - x0)
            if (frame_header.height, frame_header.width) != shape or (
                frame_header.dtype != header.dtype
            ):
                raise DeviceError(
                    f"twin at {self._where()}: a region of {frame_header.height} x "
                    f"{frame_header.width} {frame_header.dtype} for a box of {shape[0]} x "
                    f"{shape[1]} {header.dtype}; refused"
                )
            return decode_frame(frame_header, data)
        error = decode_error(line)
        message = error[1] if error is not None else f"unexpected answer {line[:60]!r}"
        raise DeviceError(f"twin at {self._where()}: {REGION}: {message}")

    def stage(self, request: str, count: int) -> tuple[float, ...]:
        """Send a stage request; the ``count`` numbers of its ``OK`` answer.

        Raises
        ------
        LimitError
            A move the twin refused as outside the stage's travel (nothing moved).
        DeviceError, DeviceTimeoutError
            Any other refusal or failure.
        """
        line, _ = self.request(request)
        values = parse_numbers(line, count)
        if values is not None:
            return values
        error = decode_error(line)
        if error is None:
            raise DeviceError(f"twin at {self._where()}: unexpected answer {line[:60]!r}")
        kind, message = error
        if kind == KIND_LIMIT:
            raise LimitError(f"twin: {message}")
        raise error_of_kind(kind)(f"twin at {self._where()}: {message}")

    def set_exposure_ms(self, camera: str, exposure_ms: float) -> None:
        """Set a camera's exposure, ms."""
        line, _ = self.request(exposure_request(camera, exposure_ms))
        if line != OK:
            raise DeviceError(f"twin: exposure of {camera} not accepted ({line[:80]})")


class TwinFrame:
    """A frame the twin exposed and keeps, read by region
    (a :class:`~microcal.vision.lazy_frame.RegionFrame`): each :meth:`region` is one REGION
    request, so a look at the tip's neighbourhood costs its pixels, not the whole frame's.

    The twin keeps its last :data:`~microcal.devices.twin_protocol.KEPT_FRAMES` frames: a
    frame read after that many more were snapped is a :class:`DeviceError`.
    """

    def __init__(self, client: FrameClient, header: SnapHeader) -> None:
        self._client, self._header = client, header
        self._full: NDArray[Any] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the whole frame, px."""
        return self._header.height, self._header.width

    def region(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[Any]:
        """The frame's pixels over [x0, x1) x [y0, y1) (clipped to the frame), a new array."""
        h, w = self.shape
        x0, y0, x1, y1 = max(0, int(x0)), max(0, int(y0)), min(w, int(x1)), min(h, int(y1))
        if self._full is not None:
            return self._full[y0:y1, x0:x1].copy()
        if x1 <= x0 or y1 <= y0:
            return np.zeros((max(y1 - y0, 0), max(x1 - x0, 0)), dtype=DTYPES[self._header.dtype])
        return self._client.region(self._header, (x0, y0, x1, y1)).copy()

    def full(self) -> NDArray[Any]:
        """The whole frame (made once)."""
        if self._full is None:
            h, w = self.shape
            self._full = self.region(0, 0, w, h)
        return self._full


class TwinCamera(SimpleCameraDevice):  # type: ignore[misc, unused-ignore]  # Any without stubs
    """One of the twin's cameras as a pure-Python Micro-Manager camera.

    Parameters
    ----------
    client : FrameClient
    name : str
        The camera's name in the twin.
    shape_px : (height, width)
        Sensor size, px.
    dtype : str
        ``"uint8"`` or ``"uint16"``.
    exposure_ms : float
        The camera's exposure, ms.
    regions : bool
        Its frames are read by region (:attr:`grab_lazy`; the twin's INFO says which).
    """

    def __init__(
        self, client: FrameClient, name: str, shape_px: tuple[int, int], dtype: str,
        exposure_ms: float, *, regions: bool = False,
    ) -> None:  # fmt: skip
        super().__init__()
        self._regions = bool(regions)
        self._client, self._name = client, name
        self._shape_px = (int(shape_px[0]), int(shape_px[1]))
        self._dtype = DTYPES[dtype]
        self._exposure_ms = float(exposure_ms)

    def sensor_shape(self) -> tuple[int, int]:
        """(height, width), px."""
        return self._shape_px

    def get_exposure(self) -> float:
        """Exposure, ms."""
        return self._exposure_ms

    def set_exposure(self, exposure: float) -> None:
        """Set the exposure, ms (sent to the twin)."""
        self._client.set_exposure_ms(self._name, float(exposure))
        self._exposure_ms = float(exposure)

    def dtype(self) -> np.dtype[Any]:
        """The frames' pixel type."""
        return self._dtype

    def snap(self, buffer: NDArray[Any]) -> Mapping[str, Any]:
        """Fill ``buffer`` (height, width) with one frame from the twin.

        Raises
        ------
        DeviceError
            A frame of another shape or pixel type than the camera's (never broadcast).
        """
        frame = self._client.grab(self._name)
        if frame.shape != self._shape_px or frame.dtype != self._dtype:
            (h, w), (sh, sw) = frame.shape, self._shape_px
            raise DeviceError(
                f"twin: a {h} x {w} {frame.dtype.name} frame from camera {self._name!r} of "
                f"{sh} x {sw} {self._dtype.name}; is the twin the one its rig was loaded from?"
            )
        buffer[:] = frame
        return {}

    @property
    def grab_lazy(self) -> Callable[[], TwinFrame] | None:
        """A grab of one frame exposed by the twin and read by region (:class:`TwinFrame`),
        for a camera the twin says is read so (the ``patch`` preset's); None for the others,
        whose whole frames a snap fetches. The Micro-Manager bridge's cameras hand it on
        (``MMCamera.grab_lazy``)."""
        return self._snap_frame if self._regions else None

    def _snap_frame(self) -> TwinFrame:
        frame = self._client.snap(self._name)
        if frame.shape != self._shape_px:
            (h, w), (sh, sw) = frame.shape, self._shape_px
            raise DeviceError(
                f"twin: a {h} x {w} frame from camera {self._name!r} of {sh} x {sw}; is the "
                "twin the one its rig was loaded from?"
            )
        return frame


def load(core: Any, address: str = "127.0.0.1", port: int = FRAMES_PORT,
         timeout_s: float = 10.0) -> None:  # fmt: skip
    """Load the twin's cameras, and its stages where it has some (the ``patch`` preset's
    focus and X-Y stage, :mod:`microcal.devices.twin_stages`), into a ``UniMMCore`` (the
    rig's ``python_devices`` loader).

    Parameters
    ----------
    core : pymmcore_plus.experimental.unicore.UniMMCore
    address, port :
        The twin's frame server (``microcal twin --frames-port``).
    timeout_s : float
        Longest wait for one answer (a frame), s.

    Raises
    ------
    DeviceError
        No twin there (``no digital twin at ADDR:PORT; start it with microcal twin ...``),
        or it does not answer as one (a camera whose frames would exceed the protocol's
        limit, say).
    """
    client = FrameClient(str(address), int(port), float(timeout_s))
    info = client.info()
    for cam in info["cameras"]:
        try:
            args = info_camera(cam)
        except (KeyError, TypeError, ValueError):
            raise DeviceError(f"twin at {address}:{port}: a camera described as {cam!r}") from None
        name, (h, w), dtype, _ = args
        if dtype not in DTYPES:
            raise DeviceError(f"twin at {address}:{port}: camera pixel type {dtype!r}")
        problem = frame_size_problem(h, w, dtype)
        if problem is not None:  # never a sensor the protocol cannot carry a frame of
            raise DeviceError(
                f"twin at {address}:{port}: camera {name!r} of {h} x {w} {dtype}: {problem}"
            )
        core.loadPyDevice(name, TwinCamera(client, *args, regions=info_regions(cam)))
    load_stages(core, client, info["stages"])
