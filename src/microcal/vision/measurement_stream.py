"""Poses measured while the run is still acquiring: each camera's track in a forked process of
its own, fed every pose's frames as the acquisition keeps them.

:class:`MeasurementStream` gives what :func:`~microcal.vision.measurement.measure_poses` gives
for the same frames, number for number: each camera's poses are measured in order by the same
:func:`~microcal.vision.measurement.camera_track`, and the poses judged and triangulated by
the same :func:`~microcal.vision.measurement.measurements_of_tracks`. Only when differs: the
measuring runs on another core while the next poses are acquired, instead of after them.
Where forking is not safe (:func:`~microcal._parallel.can_fork`), the poses are measured here,
in turn, when the results are asked for.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import queue
import weakref
from collections.abc import Callable, Mapping, Sequence
from multiprocessing import get_context
from typing import Any

from .._parallel import _portable, can_fork, ignore_interrupts
from .._validation import FloatArray
from ..errors import FormatError
from ..geometry import AnyCamera
from .measurement import (
    AnyFrames,
    PoseMeasurement,
    Seen,
    camera_track,
    measure_poses,
    measurements_of_tracks,
)
from .targets import Target
from .tip_target import TipTarget

__all__ = ["NICE", "MeasurementStream"]

#: How much lower the measuring processes' priority is than the run's (``os.nice``).
NICE = 5


def _track_worker(
    poses: Sequence[int],
    commands_um: FloatArray,
    camera: AnyCamera,
    name: str,
    target: Target | TipTarget,
    fed: Any,
    conn: Any,
    ticks: Any,
    reader: Any,
) -> None:
    """One camera's track from the frames fed to it, pose after pose; the track (or the
    error) sent back through ``conn`` (``reader``, the caller's end, closed here)."""
    reader.close()
    ignore_interrupts()
    # the poses only need measuring by the end of the run: the acquisition's own processes
    # (rendering, the settle loop's searches) wait on each other and go first
    with contextlib.suppress(OSError):
        os.nice(NICE)
    parent = os.getppid()

    def load(pose: int, _name: str) -> AnyFrames:
        while True:
            try:
                got, (kind, value) = fed.get(timeout=1.0)
                break
            except queue.Empty:
                if os.getppid() != parent:  # the run's process ended without a word
                    os._exit(0)
        if got != pose:
            raise RuntimeError(f"measurement stream: pose {got} came where {pose} was due")
        if kind == "error":
            raise FormatError(value)
        frames: AnyFrames = value
        return frames

    try:
        tick = lambda: ticks.put(1)  # noqa: E731
        message: tuple[str, Any] = (
            "ok", camera_track(poses, commands_um, load, camera, name, target, tick)
        )  # fmt: skip
    except BaseException as exc:  # everything goes back to the caller
        message = ("error", _portable(exc))
    with contextlib.suppress(BrokenPipeError, ConnectionResetError):  # the caller has ended
        conn.send(message)
    conn.close()


class MeasurementStream:
    """The poses of a run measured, camera by camera, while they are acquired.

    Parameters
    ----------
    poses : sequence of int
        Every pose of the run, in the order they will be fed.
    commands_um : (N, k) float
        Their joint commands (for predicting where the board is).
    load_frames : callable (pose, camera) -> frames
        As for :func:`~microcal.vision.measurement.measure_poses`; called here when a pose is
        fed (:meth:`add`), its frames (or its ``FormatError``) sent to the camera's process.
    cameras : dict name -> camera model
        Two or more calibrated cameras.
    target : Target or TipTarget
    progress : callable (done, total), optional
        Counts a camera's frames of a pose at a time, as they are measured (reported when this
        process looks: at :meth:`add` and while :meth:`results` waits).
    """

    def __init__(
        self,
        poses: Sequence[int],
        commands_um: FloatArray,
        load_frames: Callable[[int, str], AnyFrames],
        cameras: Mapping[str, AnyCamera],
        target: Target | TipTarget,
        progress: Callable[[int, int], None] | None = None,
    ) -> None:
        self.poses = list(poses)
        self.commands_um = commands_um
        self.load_frames = load_frames
        self.cameras = dict(cameras)
        self.target = target
        self.progress = progress
        self._done = 0
        self._fed = 0
        self._workers: dict[str, tuple[Any, Any, Any]] = {}  # name -> (process, queue, conn)
        self._ticks: Any = None
        if can_fork() and not multiprocessing.current_process().daemon:
            ctx = get_context("fork")
            self._ticks = ctx.SimpleQueue()
            for name, camera in self.cameras.items():
                fed = ctx.Queue()
                fed.cancel_join_thread()  # a process ended early does not hold this one's exit
                here, there = ctx.Pipe(duplex=False)
                proc = ctx.Process(
                    target=_track_worker,
                    args=(
                        self.poses,
                        commands_um,
                        camera,
                        name,
                        target,
                        fed,
                        there,
                        self._ticks,
                        here,
                    ),
                    daemon=True,
                )
                proc.start()
                there.close()
                self._workers[name] = (proc, fed, here)
            self._finalizer = weakref.finalize(self, _end_all, list(self._workers.values()))

    def add(self, pose: int) -> None:
        """Feed the next pose (poses come in the order given) to every camera's process."""
        due = self.poses[self._fed]
        if pose != due:
            raise RuntimeError(f"measurement stream: pose {pose} fed where {due} was due")
        self._fed += 1
        for name, (_, fed, _) in self._workers.items():
            try:
                payload: tuple[str, Any] = ("frames", list(self.load_frames(pose, name)))
            except FormatError as exc:
                payload = ("error", str(exc))
            fed.put((pose, payload))
        self._drain()

    def _drain(self) -> None:
        total = len(self.poses) * len(self.cameras)
        while self._ticks is not None and not self._ticks.empty():
            self._ticks.get()
            self._done += 1
            if self.progress:
                self.progress(self._done, total)

    def results(self) -> list[PoseMeasurement]:
        """Every pose measured (each must have been fed, unless not forked), as
        :func:`~microcal.vision.measurement.measure_poses` gives them.

        Raises
        ------
        RuntimeError
            A camera's process ended without its track (killed, or crashed in a library).
        """
        if not self._workers:
            return measure_poses(self.poses, self.commands_um, self.load_frames, self.cameras,
                                 self.target, progress=self.progress, workers=1)  # fmt: skip
        tracks: dict[str, Sequence[Seen]] = {}
        try:
            for name, (proc, _, conn) in self._workers.items():
                while not conn.poll(0.02):
                    self._drain()
                    if not proc.is_alive() and not conn.poll():
                        raise RuntimeError(
                            f"measurement of camera {name}: its process ended without a result "
                            f"(exit code {proc.exitcode}): killed, or crashed in a library"
                        )
                status, value = conn.recv()
                if status == "error":
                    raise value
                tracks[name] = value
            self._drain()
        finally:
            self.close()
        return measurements_of_tracks(self.poses, tracks, self.cameras, self.target)

    def close(self) -> None:
        """End every camera's process still running (the results are no longer wanted)."""
        _end_all(list(self._workers.values()))


def _end_all(workers: list[tuple[Any, Any, Any]]) -> None:
    for proc, _, conn in workers:
        if proc.is_alive():
            proc.terminate()
        proc.join()
        conn.close()
