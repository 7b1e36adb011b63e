"""The digital twin's cameras as Micro-Manager devices (pymmcore-plus ``unicore``).

A rig file's ``[micromanager]`` table names ``python_devices =
"microcal.devices.twin_camera:load"`` with ``options = {address = ..., port = ...}``: the
Micro-Manager bridge then calls :func:`load`, which asks the twin's frame server
(:mod:`microcal.sim.twin`) for its cameras and loads one :class:`TwinCamera` per camera,
labelled with the camera's name. Each snap fetches one frame (``GRAB <camera>``), so the
frames reach microcal through ``devices.micromanager.MMCamera`` as a real camera's would.

A dropped frame is a :class:`FrameError` and a frame that does not come in time a
:class:`DeviceTimeoutError` (both transient: grab again); a twin that cannot be reached is a
one-line :class:`DeviceError` saying how to start it.
"""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pymmcore_plus.experimental.unicore import SimpleCameraDevice

from ..errors import DeviceError, DeviceTimeoutError, FrameError

__all__ = ["FRAMES_PORT", "FrameClient", "TwinCamera", "load"]

#: The frame server's default port (``microcal twin --frames-port``).
FRAMES_PORT = 55561
_MAX_HEADER_BYTES = 1 << 16
_MAX_FRAME_BYTES = 1 << 28  # 256 MiB: far above any sensor here
_DTYPES: dict[str, np.dtype[Any]] = {"uint8": np.dtype(np.uint8), "uint16": np.dtype("<u2")}


class FrameClient:
    """One connection to the twin's frame server, shared by its cameras (thread-safe).

    A connection that breaks is opened again once per request.

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
        self._buffer = b""
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
        self._sock, self._buffer = None, b""

    def _read_until(self, n: int | None, deadline: float) -> bytes:
        """The next line (``n`` None, without its end) or the next ``n`` bytes."""
        assert self._sock is not None
        while (b"\n" not in self._buffer) if n is None else (len(self._buffer) < n):
            if time.monotonic() > deadline:
                raise TimeoutError
            if n is None and len(self._buffer) > _MAX_HEADER_BYTES:
                raise ConnectionError("an answer line too long: not a microcal twin")
            chunk = self._sock.recv(1 << 20)
            if not chunk:
                raise ConnectionError("closed by the twin")
            self._buffer += chunk
        if n is None:
            line, _, self._buffer = self._buffer.partition(b"\n")
            return line.rstrip(b"\r")
        data, self._buffer = self._buffer[:n], self._buffer[n:]
        return data

    def _exchange(self, request: str) -> tuple[str, bytes]:
        """Send one request; its answer line and, after ``OK h w dtype n``, the n bytes."""
        if self._sock is None:
            self._sock = self._open()
        self._sock.sendall(request.encode("ascii") + b"\r\n")
        deadline = time.monotonic() + self.timeout_s
        line = self._read_until(None, deadline).decode("ascii", errors="replace")
        words = line.split()
        if request.startswith("GRAB ") and len(words) == 5 and words[0] == "OK":
            nbytes = int(words[4])
            if not 0 <= nbytes <= _MAX_FRAME_BYTES:
                raise ConnectionError(f"a frame of {nbytes} bytes announced")
            return line, self._read_until(nbytes, deadline)
        return line, b""

    def request(self, request: str) -> tuple[str, bytes]:
        """Send one request and read its answer (the line, and a frame's bytes).

        Raises
        ------
        DeviceError
            The twin cannot be reached, or the connection broke twice.
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
                except (ConnectionError, OSError, ValueError) as exc:
                    self._drop()
                    if attempt == 1:
                        raise DeviceError(
                            f"twin at {self._where()}: connection lost ({exc}); is it still "
                            "running?"
                        ) from None
        raise AssertionError("unreachable")

    def info(self) -> dict[str, object]:
        """The twin's INFO as it answered (its cameras under ``cameras``, a list of objects
        with name, width, height, dtype, exposure_ms ...; checked by their reader)."""
        line, _ = self.request("INFO")
        try:
            info = json.loads(line)
            if not isinstance(info, dict):
                raise TypeError("not an object")
            cameras = list(info["cameras"])
        except (ValueError, KeyError, TypeError):
            raise DeviceError(
                f"{self._where()} answered {line[:60]!r} to INFO: not a microcal twin's frame "
                "server (is the port the MCS2 one?)"
            ) from None
        return {**info, "cameras": cameras}

    def grab(self, camera: str) -> NDArray[np.unsignedinteger]:
        """One frame of a camera, (height, width), uint8 or uint16.

        Raises
        ------
        FrameError, DeviceTimeoutError
            The twin lost the frame or it came too late (grab again).
        DeviceError
            Any other failure.
        """
        line, data = self.request(f"GRAB {camera}")
        words = line.split()
        if len(words) == 5 and words[0] == "OK" and words[3] in _DTYPES:
            try:
                return np.frombuffer(data, _DTYPES[words[3]]).reshape(int(words[1]), int(words[2]))
            except ValueError:
                pass  # a size that does not match: said below
        kind, _, message = line.partition(" ")[2].partition(" ")
        if words[:1] == ["ERR"]:
            error = {"frame": FrameError, "timeout": DeviceTimeoutError}.get(kind, DeviceError)
            raise error(message or line)
        raise DeviceError(f"twin at {self._where()}: unexpected answer {line[:60]!r} to GRAB")

    def set_exposure_ms(self, camera: str, exposure_ms: float) -> None:
        """Set a camera's exposure, ms."""
        line, _ = self.request(f"EXPOSURE {camera} {exposure_ms!r}")
        if line != "OK":
            raise DeviceError(f"twin: exposure of {camera} not accepted ({line[:80]})")


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
    """

    def __init__(
        self, client: FrameClient, name: str, shape_px: tuple[int, int], dtype: str,
        exposure_ms: float,
    ) -> None:  # fmt: skip
        super().__init__()
        self._client, self._name = client, name
        self._shape_px = (int(shape_px[0]), int(shape_px[1]))
        self._dtype = _DTYPES[dtype]
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
        """Fill ``buffer`` (height, width) with one frame from the twin."""
        buffer[:] = self._client.grab(self._name)
        return {}


def load(core: Any, address: str = "127.0.0.1", port: int = FRAMES_PORT,
         timeout_s: float = 10.0) -> None:  # fmt: skip
    """Load the twin's cameras into a ``UniMMCore`` (the rig's ``python_devices`` loader).

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
        or it does not answer as one.
    """
    client = FrameClient(str(address), int(port), float(timeout_s))
    cameras = client.info()["cameras"]
    for cam in cameras if isinstance(cameras, list) else []:
        try:
            if not isinstance(cam, dict):
                raise TypeError("not an object")
            shape = (int(cam["height"]), int(cam["width"]))
            args = (str(cam["name"]), shape, str(cam["dtype"]), float(cam["exposure_ms"]))
        except (KeyError, TypeError, ValueError):
            raise DeviceError(f"twin at {address}:{port}: a camera described as {cam!r}") from None
        if args[2] not in _DTYPES:
            raise DeviceError(f"twin at {address}:{port}: camera pixel type {args[2]!r}")
        core.loadPyDevice(args[0], TwinCamera(client, *args))
