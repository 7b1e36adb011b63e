"""The digital twin and its camera client against hostile peers: every read bounded, no peer
trusted. Each network test runs in its own network namespace with only loopback (``netns``)
and stops every twin, server, socket and thread it started.

The bounds: a line's length, a frame's size (checked before a byte of it is read), a
connection's idle time, the number of clients, a request's time; and one slow request (a long
exposure) does not hold up the others.
"""

from __future__ import annotations

import json
import re
import resource
import socket
import threading
import time
import tracemalloc

import numpy as np
import pytest

from microcal.devices.smaract_mcs2 import MCS2Manipulator
from microcal.devices.twin_protocol import KIND_FRAME, encode_error, encode_frame
from microcal.errors import DeviceError, FrameError, InputError
from microcal.sim import platform
from microcal.sim.frame_server import FramePeer
from microcal.sim.scaled_clock import ScaledClock
from microcal.sim.twin import Twin


def _twin_camera():
    """The twin's camera module (its cameras are Micro-Manager devices: microcal[mm])."""
    pytest.importorskip("pymmcore_plus", reason="the twin's cameras need microcal[mm]")
    from microcal.devices import twin_camera

    return twin_camera


WITHIN_S = 1.0  # "answers within 1 s": a behavioural bound (a blocked server takes 60 s)
LIMITS_UM = [[-500.0, 8500.0], [-500.0, 8500.0], [-500.0, 5300.0]]
HOST = "127.0.0.1"


# --- helpers ---------------------------------------------------------------------------------
def connect(port: int, timeout_s: float = 2.0) -> socket.socket:
    sock = socket.create_connection((HOST, port), timeout=timeout_s)
    sock.settimeout(timeout_s)
    return sock


def read_line(sock: socket.socket, within_s: float = 2.0) -> bytes | None:
    """The next line the peer sends (without its end), or None if it closed first."""
    data = b""
    deadline = time.monotonic() + within_s
    while b"\n" not in data:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"no answer line within {within_s:g} s (got {data[:80]!r})")
        sock.settimeout(left)
        try:
            chunk = sock.recv(1 << 16)
        except TimeoutError:
            continue
        except ConnectionResetError:
            return None
        if not chunk:
            return data or None
        data += chunk
    return data.partition(b"\n")[0].rstrip(b"\r")


def closed_by_peer(sock: socket.socket, within_s: float, trickle: bytes = b"") -> bool:
    """True once the peer closes ``sock`` (reset or end of stream) within ``within_s``;
    meanwhile ``trickle`` is sent every 0.1 s (a line that never ends)."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            if trickle:
                sock.send(trickle)
            sock.settimeout(0.1)
            if sock.recv(1 << 16) == b"":
                return True
        except TimeoutError:
            continue
        except OSError:  # reset, broken pipe: closed
            return True
    return False


def timed(what, *args):
    """(what(*args), the wall seconds it took)."""
    t0 = time.monotonic()
    value = what(*args)
    return value, time.monotonic() - t0


def mcs2_position_um(port: int) -> np.ndarray:
    """A real client: the MCS2 driver connects and reads the manipulator's position."""
    m = MCS2Manipulator(HOST, {"x": 0, "y": 1, "z": 2}, LIMITS_UM, port=port, timeout_s=2.0)
    with m:
        return m.position_um()


def frames_info(port: int) -> dict:
    """A real client: the twin's cameras' client asks for INFO."""
    client = _twin_camera().FrameClient(HOST, port, timeout_s=2.0)
    try:
        return client.info()
    finally:
        client.close()


def assert_real_clients_answered(twin: Twin) -> None:
    position, took = timed(mcs2_position_um, twin.mcs2_port)
    assert position.shape == (3,)
    assert took < WITHIN_S, f"the MCS2 peer answered after {took:.2f} s"
    info, took = timed(frames_info, twin.frames_port)
    assert [c["name"] for c in info["cameras"]] == ["top", "side"]
    assert took < WITHIN_S, f"the frame server answered after {took:.2f} s"


def twin(**kwargs) -> Twin:
    return Twin(seed=0, mcs2_port=0, frames_port=0, **kwargs)


# --- (a) endless lines -----------------------------------------------------------------------
def _flood(port: int, dropped: list[bool], stop: threading.Event) -> None:
    """Megabytes without a newline; ``dropped`` gets whether the server dropped them."""
    chunk = b"x" * 65536
    with connect(port, timeout_s=0.5) as sock:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and not stop.is_set():
            try:
                sock.sendall(chunk)
            except TimeoutError:
                continue  # the server does not read: not dropped yet
            except OSError:
                dropped.append(True)
                return
    dropped.append(False)


def test_an_endless_line_is_dropped_and_real_clients_still_get_answers(netns):
    with twin(time_scale=20.0) as served:
        ports = (served.mcs2_port, served.frames_port)
        # megabytes without a newline, on each server, while real clients ask
        stop = threading.Event()
        dropped: list[bool] = []
        floods = [threading.Thread(target=_flood, args=(p, dropped, stop)) for p in ports]
        for flood in floods:
            flood.start()
        try:
            assert_real_clients_answered(served)
        finally:
            stop.set()
            for flood in floods:
                flood.join(timeout=10.0)
        assert dropped == [True, True]
        # lines that never end, a few bytes at a time, on many connections at once
        slow = [connect(p) for p in ports for _ in range(16)]
        try:
            for sock in slow:
                sock.sendall(b":CHAN0:POS? and never a newline " * 3)
            assert_real_clients_answered(served)
        finally:
            for sock in slow:
                sock.close()
    # a line that never ends is no request: its connection is idle and dropped, although
    # bytes keep coming
    with twin(idle_timeout_s=0.5) as served:
        for port in (served.mcs2_port, served.frames_port):
            with connect(port) as sock:
                t0 = time.monotonic()
                assert closed_by_peer(sock, within_s=3.0, trickle=b"y")
                assert 0.4 < time.monotonic() - t0 < 2.0
        assert_real_clients_answered(served)


# --- (b) idle connections --------------------------------------------------------------------
def test_fifty_idle_connections_leave_room_for_a_real_client(netns):
    with twin(time_scale=20.0) as served:
        idle = [connect(p) for p in (served.mcs2_port, served.frames_port) for _ in range(50)]
        try:
            time.sleep(0.3)  # every one accepted
            assert_real_clients_answered(served)
        finally:
            for sock in idle:
                sock.close()


def test_beyond_max_clients_a_connection_is_refused_at_once_and_idle_ones_are_dropped(netns):
    with twin(time_scale=20.0, max_clients=4, idle_timeout_s=0.5) as served:
        frames, mcs2 = served.frames_port, served.mcs2_port
        idle = [connect(p) for p in (frames, mcs2) for _ in range(4)]
        try:
            time.sleep(0.1)  # all four accepted on each server
            with connect(frames) as late:  # the frame server says why, then closes
                line, took = timed(read_line, late, WITHIN_S)
                assert line is not None
                assert line.startswith(b"ERR busy "), line
                assert b"max_clients" in line
                assert took < WITHIN_S
                assert read_line(late, WITHIN_S) is None
            with connect(mcs2) as late:  # the controller's protocol has no such line: closed
                assert closed_by_peer(late, within_s=WITHIN_S)
            with pytest.raises(DeviceError, match=r"busy: .*max_clients"):
                frames_info(frames)
            # the idle ones are dropped after the idle timeout, freeing their slots
            t0 = time.monotonic()
            assert all(closed_by_peer(sock, within_s=3.0) for sock in idle)
            assert time.monotonic() - t0 < 2.0
        finally:
            for sock in idle:
                sock.close()
        assert_real_clients_answered(served)
        # a client that keeps asking is not idle: its one connection is kept
        with connect(frames) as sock:
            for _ in range(8):
                sock.sendall(b"INFO\r\n")
                line = read_line(sock, WITHIN_S)
                assert line is not None
                assert json.loads(line)["format"] == "microcal.twin/1"
                time.sleep(0.2)


@pytest.mark.parametrize(
    ("bound", "says"),
    [
        ({"max_clients": 0}, "max_clients: expected a number >= 1, got 0"),
        ({"max_clients": 2.5}, "max_clients: expected an integer, got 2.5"),
        ({"idle_timeout_s": 0}, "idle_timeout_s: expected a number > 0, got 0"),
        ({"request_timeout_s": float("inf")}, "request_timeout_s: expected a finite number"),
    ],
)
def test_the_bounds_are_checked(bound, says):
    with pytest.raises(InputError, match=re.escape(says)):
        Twin(**bound)


# --- (c) a long exposure ---------------------------------------------------------------------
def test_a_long_exposure_does_not_hold_up_the_other_devices(netns):
    with twin() as served:  # real time: a 60 s exposure takes 60 s
        with connect(served.frames_port) as slow:
            slow.sendall(b"EXPOSURE top 60000\r\n")
            assert read_line(slow) == b"OK"
            slow.sendall(b"GRAB top\r\n")
            time.sleep(0.3)  # the frame is exposing
            position, took = timed(mcs2_position_um, served.mcs2_port)
            assert took < WITHIN_S, f"the MCS2 peer answered after {took:.2f} s"
            assert np.isfinite(position).all()
            info, took = timed(frames_info, served.frames_port)
            assert took < WITHIN_S, f"INFO answered after {took:.2f} s"
            cameras = {c["name"]: c for c in info["cameras"]}
            assert cameras["top"]["exposure_ms"] == 60000.0
            client = _twin_camera().FrameClient(HOST, served.frames_port, timeout_s=2.0)
            try:
                frame, took = timed(client.grab, "side")  # the other camera's frame
            finally:
                client.close()
            assert frame.shape == (cameras["side"]["height"], cameras["side"]["width"])
            assert took < WITHIN_S, f"the side camera's frame came after {took:.2f} s"
        t0 = time.monotonic()
        served.close()  # the exposure's wait ends with the twin
        assert time.monotonic() - t0 < 3.0


def test_a_request_longer_than_the_request_timeout_answers_err_timeout(netns):
    with twin(request_timeout_s=0.5) as served, connect(served.frames_port) as sock:
        sock.sendall(b"EXPOSURE top 60000\r\n")
        assert read_line(sock) == b"OK"
        sock.sendall(b"GRAB top\r\n")
        line, took = timed(read_line, sock, 3.0)
        assert line is not None
        assert line.startswith(b"ERR timeout "), line
        assert b"0.5 s" in line
        assert 0.4 < took < 1.5
        # the connection goes on: the next requests are answered
        sock.sendall(b"EXPOSURE top 20\r\nGRAB top\r\n")
        assert read_line(sock) == b"OK"
        assert read_line(sock) == b"OK 1200 1600 uint8 1920000"


# --- (d), (e) a hostile frame server ---------------------------------------------------------
class HostileFrameServer:
    """A frame server that answers every request with ``answers[word]`` (then, for a GRAB,
    ``stream_bytes`` zero bytes, or none); it counts the requests it received."""

    def __init__(self, answers: dict[str, bytes], stream_bytes: int = 0) -> None:
        self.answers, self.stream_bytes = answers, stream_bytes
        self.requests: list[str] = []
        self._stop = threading.Event()
        self._server = socket.create_server((HOST, 0))
        self._server.settimeout(0.1)
        self.port = int(self._server.getsockname()[1])
        self._threads = [threading.Thread(target=self._accept_loop)]
        self._threads[0].start()

    def _accept_loop(self) -> None:
        for _ in range(1000):  # bounded: 0.1 s per turn at most
            if self._stop.is_set():
                return
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            thread = threading.Thread(target=self._serve, args=(conn,))
            thread.start()
            self._threads.append(thread)

    def _serve(self, conn: socket.socket) -> None:
        conn.settimeout(0.1)
        buffer = b""
        with conn:
            for _ in range(1000):
                if self._stop.is_set():
                    return
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not chunk:
                    return
                buffer += chunk
                while b"\n" in buffer:
                    line, _, buffer = buffer.partition(b"\n")
                    word = line.decode("ascii").split()[0]
                    self.requests.append(word)
                    try:
                        conn.sendall(self.answers[word])
                        if word == "GRAB" and self.stream_bytes:
                            self._stream(conn)
                    except OSError:
                        return

    def _stream(self, conn: socket.socket) -> None:
        chunk = bytes(1 << 20)
        for _ in range(self.stream_bytes >> 20):
            if self._stop.is_set():
                return
            try:
                conn.sendall(chunk)
            except TimeoutError:
                continue
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5.0)
        self._server.close()

    def __enter__(self) -> HostileFrameServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


HUGE = b"OK 200000 200000 uint16 80000000000\r\n"  # 74.5 GiB announced


def test_a_frame_larger_than_the_protocols_limit_is_refused_before_anything_is_allocated(netns):
    with HostileFrameServer({"GRAB": HUGE}, stream_bytes=64 << 20) as hostile:
        client = _twin_camera().FrameClient(HOST, hostile.port, timeout_s=2.0)
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        tracemalloc.start()
        try:
            with pytest.raises(DeviceError) as refused:
                client.grab("top")
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
            client.close()
        grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - rss0
        message = str(refused.value)
        assert len(message.splitlines()) == 1
        assert "80000000000 bytes" in message
        assert "limit of 268435456 bytes" in message
        assert peak < 500e6, peak  # bytes traced (numpy's arrays included)
        assert grown < 500e6, grown  # the process's peak resident memory
        assert hostile.requests == ["GRAB"]  # refused, not asked again


@pytest.mark.parametrize(
    ("header", "says"),
    [
        (b"OK 2 2 uint8 1000", "declares 1000 bytes for a 2 x 2 uint8 frame of 4 bytes"),
        (b"OK 200000 200000 uint16 100", "declares 100 bytes for a 200000 x 200000 uint16 frame of 80000000000 bytes"),
        (b"OK 2 2 uint16 4", "declares 4 bytes for a 2 x 2 uint16 frame of 8 bytes"),
        (b"OK -2 -2 uint8 4", "a frame of -2 x -2 pixels"),
        (b"OK 2 2 float64 32", "pixel type 'float64'"),
        (b"OK 2 two uint8 4", "not integers"),
    ],
)  # fmt: skip
def test_a_frame_header_inconsistent_with_its_shape_is_refused_at_once(netns, header, says):
    with HostileFrameServer({"GRAB": header + b"\r\n"}) as hostile:
        client = _twin_camera().FrameClient(HOST, hostile.port, timeout_s=3.0)
        try:
            t0 = time.monotonic()
            with pytest.raises(DeviceError) as refused:
                client.grab("top")
            took = time.monotonic() - t0
        finally:
            client.close()
        message = str(refused.value)
        assert len(message.splitlines()) == 1
        assert says in message
        assert type(refused.value) is DeviceError  # not transient: no grab again
        assert took < WITHIN_S  # at once, without waiting for bytes that never come


def test_the_cameras_refuse_a_sensor_or_frame_other_than_announced(netns):
    pytest.importorskip("pymmcore_plus")
    from pymmcore_plus.experimental.unicore import UniMMCore

    from microcal.devices.twin_camera import load

    camera = {"name": "top", "width": 200000, "height": 200000, "bit_depth": 16,
              "dtype": "uint16", "pixel_size_um": 4.4, "exposure_ms": 20.0}  # fmt: skip
    info = json.dumps({"format": "microcal.twin/1", "cameras": [camera]}).encode() + b"\r\n"
    refused = pytest.raises(DeviceError, match=r"camera 'top' of 200000 x 200000 uint16.*limit")
    with HostileFrameServer({"INFO": info}) as hostile, refused:
        load(UniMMCore(), HOST, hostile.port, timeout_s=2.0)
    # a frame of another shape than the camera's sensor
    with HostileFrameServer({"GRAB": b"OK 1 4 uint8 4\r\n\x01\x02\x03\x04"}) as hostile:
        client = _twin_camera().FrameClient(HOST, hostile.port, timeout_s=2.0)
        try:
            cam = _twin_camera().TwinCamera(client, "top", (4, 4), "uint8", 20.0)
            buffer = np.zeros((4, 4), np.uint8)
            with pytest.raises(
                DeviceError, match=r"a 1 x 4 uint8 frame from camera 'top' of 4 x 4 uint8"
            ):
                cam.snap(buffer)
        finally:
            client.close()


@pytest.mark.parametrize(
    ("answers", "ask", "says"),
    [
        ({"SNAP": b"OK 1 200000 200000 uint16\r\n"}, "snap", "above the protocol's limit"),
        ({"SNAP": b"OK one 2 2 uint8\r\n"}, "snap", "not integers"),
        ({"SNAP": b"OK 1 4 4 float64\r\n"}, "snap", "pixel type 'float64'"),
        ({"SNAP": b"OK 1 4 4 uint8\r\n", "REGION": b"OK 1 4 uint8 4\r\n\x01\x02\x03\x04"},
         "region", "a region of 1 x 4 uint8 for a box of 2 x 2 uint8"),
        ({"SNAP": b"OK 1 4 4 uint8\r\n", "REGION": b"OK 2 2 uint8 99\r\n"}, "region",
         "declares 99 bytes"),
        ({"POS": b"OK 1e999 0\r\n"}, "stage", "unexpected answer"),
        ({"POS": b"OK 1 2 3\r\n"}, "stage", "unexpected answer"),
    ],
)  # fmt: skip
def test_a_hostile_snap_region_or_stage_answer_is_refused_in_one_line(netns, answers, ask, says):
    """The region reads and the stages of the twin's ``patch`` preset trust no answer."""
    with HostileFrameServer(answers) as hostile:
        client = _twin_camera().FrameClient(HOST, hostile.port, timeout_s=2.0)
        asks = {"stage": lambda: client.stage("POS XYStage", 2),
                "snap": lambda: client.snap("scope"),
                "region": lambda: client.snap("scope").region(0, 0, 2, 2)}  # fmt: skip
        try:
            with pytest.raises(DeviceError) as refused:
                asks[ask]()
        finally:
            client.close()
        message = str(refused.value)
        assert len(message.splitlines()) == 1
        assert says in message


def test_a_stage_described_as_no_stage_of_the_protocol_is_refused(netns):
    pytest.importorskip("pymmcore_plus")
    from pymmcore_plus.experimental.unicore import UniMMCore

    from microcal.devices.twin_camera import load

    for stage in ({"name": "Z", "kind": "rotary", "limits_um": [[0, 1]]},
                  {"name": "Z", "kind": "focus", "limits_um": [[1, 0]]},
                  {"name": "XY", "kind": "xy", "limits_um": [[0, 1]]}):  # fmt: skip
        info = json.dumps({"format": "microcal.twin/1", "cameras": [], "stages": [stage]})
        refused = pytest.raises(DeviceError, match="a stage described as")
        with HostileFrameServer({"INFO": info.encode() + b"\r\n"}) as hostile, refused:
            load(UniMMCore(), HOST, hostile.port, timeout_s=2.0)


# --- the same simulation for well-behaved clients --------------------------------------------
class FrozenClock(ScaledClock):
    """A scaled clock stopped at one instant (its waits still wait): frames that depend only
    on the requests, not on when they came."""

    def now_s(self) -> float:
        return 12.5


def test_frames_waited_out_without_the_lock_are_the_ones_rendered_with_it():
    """The frame server defers a grab's exposure past the lock: the same frames, byte for
    byte, as the camera grabbing with its waits inline, faults included."""
    overrides = {"side.faults.drop_rate": 0.3}
    inline = platform("thesis", 4, overrides, clock=FrozenClock(1000.0))
    served = platform("thesis", 4, overrides, clock=FrozenClock(1000.0))
    peer = FramePeer(served, threading.Lock(), preset="thesis", seed=4, time_scale=1000.0)
    for name, exposure_ms in [("top", 20.0), ("side", 20.0), ("top", 35.0), ("side", 8.0)] * 3:
        inline.cameras[name].exposure_s = exposure_ms / 1e3
        assert peer.handle(f"EXPOSURE {name} {exposure_ms}".encode()) == b"OK\r\n"
        try:
            expected = encode_frame(inline.cameras[name].grab())
        except FrameError as exc:
            expected = encode_error(KIND_FRAME, str(exc))
        t0 = time.monotonic()
        assert peer.handle(f"GRAB {name}".encode()) == expected
        assert time.monotonic() - t0 >= (exposure_ms + 30.0) / 1e3 / 1000.0  # waited, after
