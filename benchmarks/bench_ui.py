"""The station page (``microcal ui``) on the simulator, in headless Chromium: live frames per
second per camera at 640 px wide, and the latency from a click on "Go" to the first move
command reaching the manipulator.

Baselines in the same run: the server's own frame rate for one camera with no browser
(``LiveStation.frame_jpeg`` in a loop), and ``LiveStation.go`` called directly (no browser,
no HTTP). The latency is an upper bound: it starts before Playwright's click (whose own
round trips to the browser it includes) and ends when the simulated controller is sent the
first move. Served on 127.0.0.1; needs Debian's chromium and Playwright (``microcal[dev]``).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from microcal import sim
from microcal.formats.calibration_file import Calibration, write_calibration
from microcal.kinematics.manipulator_calibration import ManipulatorCalibration

from .harness import Case

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run",
        "--disable-component-update", "--disable-sync", "--disable-quic"]  # fmt: skip
WINDOW_S = 5.0
N_GOES = 7


def _truth_calibration(path: Path) -> Path:
    plat = sim.platform("thesis", seed=0)
    cams = {
        n: {"image_size_px": list(m.image_size_px), "K": m.K.tolist(), "dist": m.dist.tolist(),
            "R": m.R.tolist(), "t_um": m.t_um.tolist()}
        for n, m in plat.camera_models.items()
    }  # fmt: skip
    none = dict.fromkeys(("mean_um", "std_um", "max_um", "rms_um"), 0.0) | {
        "n_fit": 0,
        "n_validate": 0,
    }
    m1 = ManipulatorCalibration("m1", plat.manipulators["m1"].truth.static, none)
    return write_calibration(path, Calibration({"m1": m1}, cams, {}))


def _first_move_times(live) -> list[float]:
    """Record the time of every move command the simulated controller is sent."""
    times: list[float] = []
    inner = live.manipulator.device
    real = inner._move

    def move(d):
        times.append(time.perf_counter())
        real(d)

    inner._move = move
    return times


def _server_fps(live, camera: str, n: int = 60) -> float:
    start = time.perf_counter()
    for _ in range(n):
        live.frame_jpeg(camera, 640)
    return n / (time.perf_counter() - start)


def _direct_latency_s(live, targets) -> float:
    times = _first_move_times(live)
    out = []
    for p in targets:
        times.clear()
        start = time.perf_counter()
        live.go(p, "open")
        live.wait(60.0)
        out.append(times[0] - start)
    return statistics.median(out)


def run() -> list[Case]:
    from playwright.sync_api import sync_playwright

    from microcal.ui.serve import start_server
    from microcal.workflows.live import open_live_station

    with tempfile.TemporaryDirectory() as tmp:
        cal = _truth_calibration(Path(tmp) / "calibration.json")
        live = open_live_station("sim", str(cal), seed=0, frames=1, settle_s=0.0)
        baseline_fps = min(_server_fps(live, c) for c in live.cameras)
        rng = np.random.default_rng(3)
        targets = rng.uniform([2000, 2000, 1000], [5000, 5000, 3000], (N_GOES, 3))
        direct_s = _direct_latency_s(live, targets[:3])
        server = start_server(live, "127.0.0.1", 0)
        try:
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
                page = browser.new_page(viewport={"width": 1700, "height": 1000})
                page.goto(server.url)
                page.wait_for_function("Object.values(window.microcal.frames).every((n) => n > 5)")
                time.sleep(1.0)
                before = page.evaluate("({...window.microcal.frames})")
                time.sleep(WINDOW_S)
                after = page.evaluate("({...window.microcal.frames})")
                fps = {n: (after[n] - before[n]) / WINDOW_S for n in after}
                times = _first_move_times(live)
                latencies = []
                missed = 0
                page.select_option("#mode", "open")
                for p in targets:
                    page.evaluate(
                        "(p) => { window.microcal.target = {target_um: p, refusal: null}; }",
                        p.tolist(),
                    )
                    page.wait_for_function("!document.querySelector('#go').disabled")
                    times.clear()
                    start = time.perf_counter()
                    page.click("#go")
                    deadline = time.monotonic() + 30.0
                    while not times and time.monotonic() < deadline:
                        time.sleep(0.001)
                    if not times:
                        missed += 1
                        continue
                    latencies.append(times[0] - start)
                    live.wait(60.0)
                    page.wait_for_function("window.microcal.state.activity === 'idle'")
                browser.close()
        finally:
            server.stop()
    slowest = min(fps.values())
    if not latencies:
        raise RuntimeError(f"no click on Go reached the manipulator within 30 s ({missed} tried)")
    latency_s = statistics.median(latencies)
    return [
        Case("live view, slowest camera (640 px wide)", "frames/s", slowest,
             "server alone, one camera", baseline_fps, ">= 10 frames/s per camera",
             slowest >= 10.0, {"per_camera_fps": fps, "window_s": WINDOW_S}),
        Case("click on Go to the first move command (median)", "ms", 1000 * latency_s,
             "LiveStation.go called directly", 1000 * direct_s, "<= 200 ms",
             latency_s <= 0.2 and missed == 0,
             {"latencies_ms": [1000 * t for t in latencies], "goes_without_move": missed}),
    ]  # fmt: skip
