"""GigE Vision (and USB3 Vision) cameras through Aravis: ``pip install 'microcal[genicam]'``.

The camera is opened by its address (``Aravis.Camera.new("192.168.1.10")``): no discovery,
which would broadcast on every interface. Frames are software-triggered one at a time from a
running stream, so a grab takes one exposure and one transfer, not a stream start.

Aravis comes from the PyPI package ``aravis-python`` (it carries libaravis and its typelib)
with PyGObject; Debian's ``gir1.2-aravis-0.8`` and ``python3-gi`` serve as well.
"""

from __future__ import annotations

import contextlib
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DeviceError, DeviceTimeoutError, FrameError, InputError
from .base import Camera

__all__ = ["PIXEL_FORMATS", "AravisCamera", "aravis_available", "load_aravis"]

#: Pixel formats the driver reads, with their bit depth.
PIXEL_FORMATS = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono14": 14, "Mono16": 16}
N_BUFFERS = 4


def load_aravis() -> Any:
    """The ``Aravis`` GObject module, or a :class:`DeviceError` saying what to install."""
    try:
        with contextlib.suppress(ImportError):
            import aravis  # noqa: F401  (the PyPI package registers its typelib)
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ImportError, ValueError) as exc:
        raise DeviceError(
            f"GigE Vision cameras need Aravis ({exc}); install it with: "
            f"pip install 'microcal[genicam]'"
        ) from None
    return Aravis


def aravis_available() -> str | None:
    """None when Aravis can be loaded, else the reason."""
    try:
        load_aravis()
    except DeviceError as exc:
        return str(exc)
    return None


class AravisCamera(Camera):
    """One GigE Vision camera, software-triggered single frames.

    Parameters
    ----------
    address : str
        The camera's IP address (or an Aravis device id).
    name : str
        The camera's name in microcal (``top``, ``side``).
    exposure_s : float
        Exposure time, s.
    pixel_format : str
        One of :data:`PIXEL_FORMATS`.
    region_px : (x, y, width, height), optional
        Sensor region to read (the whole sensor by default).
    timeout_s : float
        Longest wait for one frame.
    pixel_size_um : float
        The sensor's pixel pitch (for the record; the calibration does not need it).
    """

    def __init__(
        self,
        address: str,
        *,
        name: str,
        exposure_s: float = 0.01,
        pixel_format: str = "Mono8",
        region_px: tuple[int, int, int, int] | None = None,
        timeout_s: float = 2.0,
        pixel_size_um: float = 3.45,
    ) -> None:
        if pixel_format not in PIXEL_FORMATS:
            raise InputError(
                f"pixel_format: expected one of {', '.join(PIXEL_FORMATS)}, got {pixel_format!r}"
            )
        self.address = address
        self.timeout_s = float(timeout_s)
        self._aravis = load_aravis()
        self._camera: Any = None
        self._stream: Any = None
        try:
            self._camera = self._aravis.Camera.new(address)
        except Exception as exc:  # GLib.Error: the camera is not there
            raise DeviceError(
                f"{name}: cannot open the camera at {address} ({_message(exc)})"
            ) from None
        cam = self._camera
        try:
            if region_px is not None:
                cam.set_region(*region_px)
            cam.set_pixel_format_from_string(pixel_format)
            cam.set_exposure_time(exposure_s * 1e6)
            _, _, width, height = cam.get_region()
            self.vendor = f"{cam.get_vendor_name()} {cam.get_model_name()}"
            self.serial = cam.get_device_serial_number() or ""
        except Exception as exc:
            raise DeviceError(
                f"{name}: cannot configure the camera at {address} ({_message(exc)})"
            ) from None
        super().__init__(
            name, (width, height), pixel_size_um, PIXEL_FORMATS[pixel_format], exposure_s
        )
        self._start()

    def _start(self) -> None:
        cam = self._camera
        try:
            cam.set_acquisition_mode(self._aravis.AcquisitionMode.CONTINUOUS)
            cam.set_trigger("Software")
            self._stream = cam.create_stream(None, None)
            payload = cam.get_payload()
            for _ in range(N_BUFFERS):
                self._stream.push_buffer(self._aravis.Buffer.new_allocate(payload))
            cam.start_acquisition()
        except Exception as exc:
            raise DeviceError(f"{self.name}: cannot start streaming ({_message(exc)})") from None

    def _apply_exposure(self, exposure_s: float) -> None:
        try:
            self._camera.set_exposure_time(exposure_s * 1e6)
        except Exception as exc:
            raise DeviceError(f"{self.name}: exposure not accepted ({_message(exc)})") from None

    def _grab(self) -> NDArray[np.unsignedinteger]:
        try:
            self._camera.software_trigger()
        except Exception as exc:
            # Aravis has already resent the command: the camera is gone, not slow.
            raise DeviceError(
                f"{self.name}: camera not answering (software trigger: {_message(exc)})"
            ) from None
        buffer = self._stream.timeout_pop_buffer(int(self.timeout_s * 1e6))
        if buffer is None:
            raise DeviceTimeoutError(
                f"{self.name}: camera not answering (no frame within {self.timeout_s:g} s)"
            )
        try:
            status = buffer.get_status()
            if status != self._aravis.BufferStatus.SUCCESS:
                raise FrameError(f"{self.name}: frame incomplete ({status.value_nick})")
            h, w = buffer.get_image_height(), buffer.get_image_width()
            data = np.frombuffer(buffer.get_data(), dtype=self.dtype)
            if data.size < h * w:
                raise FrameError(f"{self.name}: frame of {data.size} pixels, expected {w} x {h}")
            frame: NDArray[np.unsignedinteger] = data[: h * w].reshape(h, w).copy()
        finally:
            self._stream.push_buffer(buffer)
        return frame

    def _close(self) -> None:
        """Stop streaming and release the stream and the camera."""
        if self._camera is not None:
            # a camera that no longer answers cannot stop: there is nothing left to do
            with contextlib.suppress(Exception):
                self._camera.stop_acquisition()
        self._stream = None
        self._camera = None


def _message(exc: BaseException) -> str:
    return str(getattr(exc, "message", None) or exc)
