"""Micro-Manager devices as microcal devices: ``pip install 'microcal[mm]'`` (pymmcore-plus).

Any XY stage plus focus (Z) stage and any camera that a Micro-Manager configuration provides
(SmarAct, Sutter, Scientifica, Sensapex, Basler, ... through their adapters) become a
:class:`~microcal.devices.base.Manipulator` and :class:`~microcal.devices.base.Camera`. The
core is either loaded from a configuration file (``.cfg``, Micro-Manager's C++ adapters) or
given pure-Python devices (pymmcore-plus's ``UniMMCore``) by a function of your own.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import FloatArray
from ..errors import DeviceError, DeviceTimeoutError, InputError, MicrocalError
from .base import Camera, Manipulator

__all__ = ["MMCamera", "MMManipulator", "mm_available", "open_core"]


def mm_available() -> str | None:
    """None when pymmcore-plus can be imported, else the reason."""
    try:
        import pymmcore_plus  # noqa: F401
    except ImportError as exc:
        return f"Micro-Manager needs pymmcore-plus ({exc}); install: pip install 'microcal[mm]'"
    return None


def open_core(
    config: str | None = None,
    python_devices: str | None = None,
    options: Mapping[str, Any] | None = None,
) -> Any:
    """A Micro-Manager core with its devices loaded and initialised.

    Parameters
    ----------
    config : str, optional
        A Micro-Manager configuration file (C++ device adapters).
    python_devices : str, optional
        ``"module:function"``: ``function(core)`` loads pure-Python devices into a
        ``UniMMCore`` (``core.loadPyDevice(label, device)``).
    """
    with _quiet("pymmcore-plus"):
        reason = mm_available()
    if reason:
        raise DeviceError(reason)
    if (config is None) == (python_devices is None):
        raise InputError("micromanager: give exactly one of 'config' or 'python_devices'")
    with _quiet("pymmcore-plus"):
        return _load_core(config, python_devices, dict(options or {}))


def _load_core(
    config: str | None, python_devices: str | None, options: Mapping[str, object]
) -> Any:
    try:
        if config is not None:
            from pymmcore_plus import CMMCorePlus

            core: Any = CMMCorePlus()
            core.loadSystemConfiguration(config)
            return core
        from pymmcore_plus.experimental.unicore import UniMMCore

        module_name, _, func_name = str(python_devices).partition(":")
        try:
            loader = getattr(importlib.import_module(module_name), func_name)
        except (ImportError, AttributeError) as exc:
            raise InputError(
                f"python_devices: cannot load {python_devices!r} ({exc}); "
                f"expected 'module:function'"
            ) from None
        core = UniMMCore()
        try:
            loader(core, **options)
        except TypeError as exc:
            raise InputError(
                f"python_devices: {python_devices} refused the options ({exc})"
            ) from None
        core.initializeAllDevices()
        return core
    except MicrocalError:
        raise  # a loader's own one-line error (its frame source not running) says it best
    except (RuntimeError, OSError) as exc:
        raise DeviceError(f"micromanager: cannot load the devices ({exc})") from None


@contextlib.contextmanager
def _quiet(name: str) -> Iterator[None]:
    """The library's own log lines stay out of the terminal: its errors become microcal's
    one-line errors (a Micro-Manager installation it cannot find, a device it cannot load)."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        logger.setLevel(level)


def _device_error(message: str, exc: RuntimeError) -> DeviceError:
    """The core's error as microcal's: a timeout is transient (tried again), others are not.

    A pure-Python device that raises microcal's own error keeps its kind (a ``FrameError``
    stays transient).
    """
    if isinstance(exc, DeviceError):
        return type(exc)(message)
    kind = DeviceTimeoutError if "timeout" in str(exc).lower() else DeviceError
    return kind(message)


def _python_device(core: Any, label: str) -> Any:
    """The pure-Python device ``label`` of a ``UniMMCore`` (None for a C++ device, a core of
    no pure-Python devices or a closed one); pymmcore-plus keeps them by label in the core's
    device manager."""
    devices = getattr(core, "_pydevices", None)
    try:
        return devices[label] if devices is not None and label in devices else None
    except (KeyError, TypeError):
        return None


class MMManipulator(Manipulator):
    """An XY stage and a focus stage of a Micro-Manager core as one 3-axis manipulator, or
    an XY stage alone as a 2-axis one (``focus`` None: joints x, y)."""

    def __init__(
        self,
        core: Any,
        *,
        xy_stage: str,
        focus: str | None,
        limits_um: ArrayLike,
        name: str = "mm",
    ) -> None:
        super().__init__(name, ("x", "y", "z") if focus is not None else ("x", "y"), limits_um)
        self.core, self.xy_stage, self.focus = core, xy_stage, focus
        self._identity = f"Micro-Manager {xy_stage}" + ("" if focus is None else f" + {focus}")
        loaded = set(core.getLoadedDevices())
        missing = [d for d in (xy_stage, focus) if d is not None and d not in loaded]
        if missing:
            raise DeviceError(
                f"{name}: device(s) {missing} not in the Micro-Manager configuration "
                f"(loaded: {sorted(loaded)})"
            )

    @property
    def identity(self) -> str:
        """``Micro-Manager <XY stage> + <focus>``: the configuration's device labels."""
        return self._identity

    def _call(self, what: str, fn: Any, *args: Any) -> Any:
        try:
            return fn(*args)
        except RuntimeError as exc:
            raise _device_error(f"{self.name}: {what}: {exc}", exc) from None

    def _move(self, d_um: FloatArray) -> None:
        self._call("XY move", self.core.setXYPosition, self.xy_stage, float(d_um[0]),
                   float(d_um[1]))  # fmt: skip
        if self.focus is not None:
            self._call("Z move", self.core.setPosition, self.focus, float(d_um[2]))

    def _position_um(self) -> FloatArray:
        xy = self._call("XY position", self.core.getXYPosition, self.xy_stage)
        if self.focus is None:
            return np.array([float(xy[0]), float(xy[1])])
        z = self._call("Z position", self.core.getPosition, self.focus)
        return np.array([float(xy[0]), float(xy[1]), float(z)])

    def _is_moving(self) -> bool:
        busy = self._call("XY state", self.core.deviceBusy, self.xy_stage)
        if self.focus is not None:
            busy = self._call("Z state", self.core.deviceBusy, self.focus) or busy
        return bool(busy)

    def _stop(self) -> None:
        self._call("XY stop", self.core.stop, self.xy_stage)
        if self.focus is not None:
            self._call("Z stop", self.core.stop, self.focus)

    def _close(self) -> None:
        self.core = None  # the core and its devices belong to whoever opened it (the rig)


class MMCamera(Camera):
    """A camera of a Micro-Manager core; each grab is one ``snapImage``."""

    def __init__(
        self,
        core: Any,
        device: str,
        *,
        name: str,
        exposure_s: float | None = None,
        pixel_size_um: float = 3.45,
    ) -> None:
        self.core, self.device = core, device
        if device not in set(core.getLoadedDevices()):
            raise DeviceError(f"{name}: camera {device!r} not in the Micro-Manager configuration")
        try:
            core.setCameraDevice(device)
            if exposure_s is not None:
                core.setExposure(device, exposure_s * 1e3)
            size = (int(core.getImageWidth()), int(core.getImageHeight()))
            bits = int(core.getImageBitDepth())
            exposure = float(core.getExposure(device)) / 1e3
        except RuntimeError as exc:
            raise DeviceError(f"{name}: cannot set up camera {device!r} ({exc})") from None
        super().__init__(name, size, pixel_size_um, bits, exposure)

    def _apply_exposure(self, exposure_s: float) -> None:
        try:
            self.core.setExposure(self.device, exposure_s * 1e3)
        except RuntimeError as exc:
            raise DeviceError(f"{self.name}: exposure not accepted ({exc})") from None

    @property
    def grab_lazy(self) -> Callable[[], Any] | None:
        """One frame read by region (a :class:`~microcal.vision.lazy_frame.RegionFrame`),
        where the camera is a pure-Python device that gives such frames (a ``grab_lazy()`` of
        its own: the digital twin's, ``devices.twin_camera``); None for any other camera,
        whose whole frames :meth:`grab` gives (``vision.lazy_frame.grab_frame`` takes either).

        The core's ``snapImage`` gives whole frames only: such a frame is asked of the device
        itself, found among the core's pure-Python devices by its label.
        """
        lazy = getattr(_python_device(self.core, self.device), "grab_lazy", None)
        if not callable(lazy):
            return None

        def grab() -> Any:
            self._check_open("grab")
            try:
                return lazy()
            except RuntimeError as exc:
                raise _device_error(f"{self.name}: no frame ({exc})", exc) from None

        return grab

    def _grab(self) -> NDArray[np.unsignedinteger]:
        try:
            self.core.setCameraDevice(self.device)
            self.core.snapImage()
            image = np.asarray(self.core.getImage())
        except RuntimeError as exc:
            raise _device_error(f"{self.name}: no frame ({exc})", exc) from None
        frame: NDArray[np.unsignedinteger] = image.astype(self.dtype, copy=True)
        return frame

    def _close(self) -> None:
        self.core = None  # the core and its devices belong to whoever opened it (the rig)
