"""Shared fixtures: seeded generators, camera pairs, and the runs a session makes once (a
12-pose acquisition, the quick demo) for all its workers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from microcal.thesis.cameras import thesis_cameras

settings.register_profile("ci", max_examples=200, deadline=None, derandomize=True)
settings.register_profile("dev", max_examples=60, deadline=None)
settings.load_profile("ci" if __import__("os").environ.get("CI") else "dev")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20121)


@pytest.fixture(scope="session")
def thesis_pair():
    return thesis_cameras()


@pytest.fixture(scope="session")
def acquired_run(tmp_path_factory) -> tuple[Path, Path]:
    """A complete simulated run of 12 poses (2 frames, regions) and the simulator's true
    cameras.json, made once per session and shared by its workers: (run directory,
    cameras.json). A test that changes the run works on a copy of it."""
    from support.cli import invoke_microcal
    from support.runs import write_true_cameras
    from support.shared import made_once

    def make(root: Path) -> None:
        out = invoke_microcal("acquire", "--rig", "sim", "--poses", 12, "--frames", "2",
                              "--store", "roi", "--out", root / "run")  # fmt: skip
        assert out.returncode == 0, out.stderr
        write_true_cameras(root / "cameras.json")

    root = made_once(tmp_path_factory, "acquired-run", make)
    return root / "run", root / "cameras.json"


#: The demo every test of a demo's files shares (``microcal demo`` with these options).
QUICK_DEMO = ("demo", "--quick", "--seed", "0")


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory) -> tuple[Path, str]:
    """One ``microcal demo --quick --seed 0`` for the whole session, shared by its workers:
    (run directory, terminal output at 200 columns). A test that changes the run directory
    works on a copy of it."""
    from typer.testing import CliRunner

    from microcal.cli import app
    from support.shared import made_once

    def make(root: Path) -> None:
        result = CliRunner().invoke(
            app, [*QUICK_DEMO, "--out", str(root / "run")], env={"COLUMNS": "200"}
        )
        assert result.exit_code == 0, result.output
        (root / "output.txt").write_text(result.output, encoding="utf-8")

    root = made_once(tmp_path_factory, "quick-demo", make)
    return root / "run", (root / "output.txt").read_text(encoding="utf-8")


@pytest.fixture
def netns():
    """The test runs in its own network namespace with only loopback (see tests/support/netns.py)."""
    from support.netns import own_network_namespace, unavailable_reason

    reason = unavailable_reason()
    if reason:
        pytest.skip(reason)
    with own_network_namespace():
        yield


@pytest.fixture
def fake_mcs2(netns):
    """A fake MCS2 controller on 127.0.0.1:55551 inside the test's network namespace."""
    from support.fake_mcs2 import FakeMCS2

    with FakeMCS2(port=55551) as fake:
        yield fake


ARV_FAKE = "arv-fake-gv-camera-0.8"


def _udp_port_bound(address: str, port: int) -> bool:
    import socket

    hexaddr = socket.inet_aton(address)[::-1].hex().upper()
    with open("/proc/net/udp", encoding="ascii") as fh:
        return any(f"{hexaddr}:{port:04X}" in line for line in fh)


@pytest.fixture
def gige_cameras(netns):
    """Start GigE Vision peers on loopback: ``start("127.0.0.1")`` runs Debian's fake camera
    (arv-fake-gv-camera-0.8), ``start("127.0.0.2", viva=(w, h))`` an in-process viva-genicam
    fake of that size. Everything started is stopped, by PID, at the end."""
    import shutil
    import time

    from microcal.devices.aravis_camera import aravis_available

    if shutil.which(ARV_FAKE) is None:
        pytest.skip(f"needs {ARV_FAKE} (Debian package aravis-tools; .ci/run installs it)")
    reason = aravis_available()
    if reason:
        pytest.skip(reason)
    procs: list[subprocess.Popen[bytes]] = []

    def start(address: str, serial: str = "MICROCAL01", viva: tuple[int, int] | None = None):
        if viva is not None:
            pytest.importorskip(
                "viva_genicam.testing", reason="needs viva-genicam (pip install viva-genicam)"
            )
            peer = Path(__file__).parent / "support" / "viva_peer.py"
            proc = subprocess.Popen([sys.executable, str(peer), str(viva[0]), str(viva[1]), address],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)  # fmt: skip
            procs.append(proc)
            assert proc.stdout is not None
            if proc.stdout.readline().strip() != b"ready":
                pytest.fail(f"viva-genicam fake camera did not start on {address}")
            return proc
        proc = subprocess.Popen([ARV_FAKE, "-i", address, "-s", serial], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        procs.append(proc)
        deadline = time.monotonic() + 5.0
        while not _udp_port_bound(address, 3956):
            if time.monotonic() > deadline or proc.poll() is not None:
                pytest.fail(f"{ARV_FAKE} did not start on {address}:3956")
            time.sleep(0.02)
        return proc

    yield start
    for proc in procs:
        proc.send_signal(18)  # SIGCONT, in case a test paused it
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


@pytest.fixture
def mm_core():
    """A Micro-Manager core (pymmcore-plus UniMMCore) with the pure-Python devices of
    tests/support/mm_devices.py."""
    pytest.importorskip("pymmcore_plus", reason="needs pymmcore-plus (pip install 'microcal[mm]')")
    from microcal.devices.micromanager import open_core

    core = open_core(python_devices="support.mm_devices:load")
    yield core
    core.unloadAllDevices()
