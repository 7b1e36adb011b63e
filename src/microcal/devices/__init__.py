"""Devices (layer 3): the protocols every backend implements, and clocks."""

from .base import Camera, Clock, Manipulator, RealClock

__all__ = ["Camera", "Clock", "Manipulator", "RealClock"]
