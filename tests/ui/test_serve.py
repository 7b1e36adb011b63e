"""``microcal ui`` as a user starts it: the address it prints, the token it needs when opened
beyond loopback, and its one-line refusals. Served inside the test's own network namespace
(only loopback exists there, so even 0.0.0.0 is reached through 127.0.0.1 alone)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from support.cli import invoke_microcal
from support.station_files import write_truth_calibration

pytest.importorskip("starlette", reason="needs Starlette (pip install 'microcal[ui]')")
pytest.importorskip("uvicorn", reason="needs uvicorn (pip install 'microcal[ui]')")


def _get(url: str, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    request = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=10) as answer:
            return answer.status, answer.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def _start(args: list[str]) -> tuple[subprocess.Popen[str], str]:
    """``microcal ui ARGS`` in the background and the address it printed."""
    env = os.environ | {"PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-m", "microcal", "ui", *args], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    assert proc.stdout is not None
    deadline = time.monotonic() + 60.0
    line = ""
    while time.monotonic() < deadline and proc.poll() is None:
        line = proc.stdout.readline()
        if line.startswith("station page: "):
            return proc, line.removeprefix("station page: ").strip()
    proc.kill()
    raise AssertionError(
        f"microcal ui did not start: {line!r} {proc.stderr.read() if proc.stderr else ''}"
    )


def _stop(proc: subprocess.Popen[str]) -> None:
    proc.terminate()  # by PID: the process this test started
    try:
        proc.wait(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=15)


@pytest.mark.slow
def test_beyond_loopback_every_request_needs_the_printed_token(netns, tmp_path: Path):
    cal = write_truth_calibration(tmp_path / "calibration.json")
    proc, url = _start(
        ["--rig", "sim", "--calibration", str(cal), "--host", "0.0.0.0", "--port", "0"]
    )
    try:
        assert "?token=" in url
        port = url.split("?")[0].rstrip("/").rsplit(":", 1)[1]
        token = url.split("?token=")[1]
        base = f"http://127.0.0.1:{port}"
        status, body = _get(f"{base}/api/state")
        assert status == 403
        assert json.loads(body) == {
            "error": "refused: this station needs its token in the URL (printed when it started)"
        }
        assert _get(f"{base}/?token={token[:-2]}")[0] == 403
        status, body = _get(f"{base}/api/layout?token={token}")
        assert status == 200
        assert [c["name"] for c in json.loads(body)["cameras"]] == ["top", "side"]
    finally:
        _stop(proc)


@pytest.mark.slow
def test_on_loopback_no_token_and_other_host_names_are_refused(netns, tmp_path: Path):
    cal = write_truth_calibration(tmp_path / "calibration.json")
    proc, url = _start(["--rig", "sim", "--calibration", str(cal), "--port", "0"])
    try:
        assert url.startswith("http://127.0.0.1:")
        assert "token" not in url
        assert _get(f"{url}api/state")[0] == 200
        status, body = _get(f"{url}api/state", {"Host": "rebound.example:80"})
        assert status == 403
        assert "refused: this station answers to" in json.loads(body)["error"]
    finally:
        _stop(proc)


def test_bad_options_are_one_line(tmp_path: Path):
    out = invoke_microcal("ui", "--calibration", tmp_path / "missing.json")
    assert out.returncode == 2
    assert out.stderr.startswith("microcal: error: ")
    assert len(out.stderr.strip().splitlines()) == 1
    out = invoke_microcal("ui", "--calibration", "c.json", "--port", "70000")
    assert out.returncode == 2
    assert "--port" in out.stderr


def test_a_busy_port_is_one_line_that_names_port_0(netns):
    """In the test's own namespace: a port this test holds is refused in one line that says
    how to get another."""
    import socket

    from microcal.errors import InputError
    from microcal.ui.serve import _bind

    held = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        held.bind(("127.0.0.1", 0))
        held.listen(1)
        port = held.getsockname()[1]
        with pytest.raises(InputError, match=rf"--port {port}: cannot listen there .*--port 0"):
            _bind("127.0.0.1", port)
        free = _bind("127.0.0.1", 0)
        free.close()
    finally:
        held.close()
