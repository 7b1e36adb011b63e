"""The station page's server in process (Starlette's test client): the token, other sites,
one controlling browser, and every bad request answered in one line with nothing moved."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("starlette", reason="needs Starlette (pip install 'microcal[ui]')")
pytest.importorskip(
    "httpx2", reason="Starlette's test client needs httpx2 (pip install 'microcal[dev]')"
)

from starlette.testclient import TestClient

from microcal.errors import DeviceError
from microcal.ui.app import create_app
from microcal.workflows.live import open_live_station
from support.station_files import write_truth_calibration

HOSTS = frozenset({"testserver"})
JSON = {"Content-Type": "application/json"}


@pytest.fixture(scope="module")
def calibration(tmp_path_factory) -> str:
    return str(write_truth_calibration(tmp_path_factory.mktemp("app") / "calibration.json"))


@pytest.fixture
def live(calibration):
    station = open_live_station("sim", calibration, seed=0, frames=2)
    yield station
    station.close()


def _browser(app) -> TestClient:
    client = TestClient(app)
    assert client.get("/").status_code == 200  # the page gives the browser its session
    return client


def test_the_page_its_layout_state_and_frames(live):
    app = create_app(live, hosts=HOSTS)
    browser = _browser(app)
    page = browser.get("/")
    assert "microcal station" in page.text
    assert "station.js" in page.text
    assert browser.get("/static/station.js").status_code == 200
    layout = browser.get("/api/layout").json()
    assert [c["name"] for c in layout["cameras"]] == ["top", "side"]
    assert browser.post("/api/claim", json={}).json() == {"role": "control"}
    state = browser.get("/api/state").json()
    assert state["role"] == "control"
    assert state["activity"] == "idle"
    frame = browser.get("/api/frame/top?w=320")
    assert frame.headers["content-type"] == "image/jpeg"
    assert frame.content[:2] == b"\xff\xd8"
    assert browser.get("/api/zoom/side?x=10&y=20&size=64").content[:2] == b"\xff\xd8"
    assert set(browser.get("/api/overlays").json()) == {"top", "side"}


def test_with_a_token_every_request_needs_it(live):
    app = create_app(live, token="s3cret-token", hosts=HOSTS)
    stranger = TestClient(app)
    for path in ("/", "/api/state", "/api/frame/top", "/static/station.js"):
        r = stranger.get(path)
        assert r.status_code == 403
        assert r.json() == {
            "error": "refused: this station needs its token in the URL (printed when it started)"
        }
    assert stranger.get("/?token=wrong").status_code == 403
    r = stranger.post("/api/stop", json={})
    assert r.status_code == 403
    assert not live.manipulator.halted
    user = TestClient(app)
    assert user.get("/?token=s3cret-token").status_code == 200
    assert user.get("/api/state").status_code == 200  # the cookie carries it from then on


def test_other_sites_and_other_host_names_are_refused(live):
    app = create_app(live, hosts=HOSTS)
    browser = _browser(app)
    browser.post("/api/claim", json={})
    r = browser.get("/api/state", headers={"Host": "attacker.example"})
    assert r.status_code == 403
    assert "answers to testserver" in r.json()["error"]
    r = browser.post("/api/go", json={"target_um": [3000, 2000, 1500]},
                     headers={"Origin": "http://attacker.example"})  # fmt: skip
    assert r.status_code == 403
    assert r.json() == {"error": "refused: a request from another site (http://attacker.example)"}
    r = browser.post(
        "/api/go",
        content=b'{"target_um": [3000, 2000, 1500]}',
        headers={"Content-Type": "text/plain"},
    )
    assert r.status_code == 400
    assert r.json() == {"error": "expected a JSON body (Content-Type: application/json)"}
    assert live.moves_started == 0


def test_the_second_browser_watches_and_cannot_move_anything(live):
    app = create_app(live, hosts=HOSTS)
    first, second = _browser(app), _browser(app)
    assert first.post("/api/claim", json={}).json() == {"role": "control"}
    assert second.post("/api/claim", json={}).json() == {"role": "watch"}
    assert second.get("/api/state").json()["role"] == "watch"
    for path, body in (("/api/go", {"target_um": [3000, 2000, 1500]}), ("/api/measure", {}),
                       ("/api/target", {"clicks": {}}), ("/api/run", {"kind": "check"}),
                       ("/api/run/cancel", {}), ("/api/focal-plane", {})):  # fmt: skip
        r = second.post(path, json=body)
        assert r.status_code == 403
        assert r.json() == {
            "error": "refused: another browser controls this station; this one watches"
        }
    assert live.moves_started == 0
    assert second.post("/api/stop", json={}).status_code == 200  # any browser may stop
    assert live.manipulator.halted


@pytest.mark.parametrize(("path", "body", "status", "message"), [
    ("/api/go", {"target_um": [1, 2]}, 400, "target_um: expected a list of 3 numbers, got [1, 2]"),
    ("/api/go", {"target_um": [1, 2, "x"]}, 400, "target_um: expected a finite number, got 'x'"),
    ("/api/go", {"target_um": [3000, 2000, 1500], "tolerance_um": -1}, 400, "tolerance: expected a number of µm > 0, got -1.0"),
    ("/api/go", {"target_um": [3000, 2000, 1500], "mode": "warp"}, 400, "mode: expected 'open' or 'closed', got 'warp'"),
    ("/api/go", {"target_um": [3000, 3000, 9000]}, 409, "outside the soft limits"),
    ("/api/go", [1, 2, 3], 400, "request body: expected a JSON object"),
    ("/api/epipolar", {"camera": "top", "x_px": None, "y_px": 3}, 400, "x_px: expected a finite number, got None"),
    ("/api/epipolar", {"camera": "left", "x_px": 1, "y_px": 3}, 400, "camera 'left': this rig has top, side"),
    ("/api/target", {"clicks": {"top": [1, 2]}}, 400, "target: a click gives a ray, not a point"),
    ("/api/target", {"clicks": {"top": [1, 2], "side": [3, 4]}, "std_px": {"top": 0}}, 400, "std_px: expected numbers of px > 0"),
    ("/api/target", {"clicks": {"top": [1, 2], "side": [3, 4]}, "first": 3}, 400, "first: expected a camera's name, got 3"),
    ("/api/target", {"clicks": {"top": [1, 2], "side": [3, 4]}, "offset_um": "up"}, 400, "offset_um: expected a finite number"),
    ("/api/focal-plane", {}, 400, "focal plane: for a one-camera rig"),
    ("/api/run", {"kind": "dance"}, 400, "run: expected one of cameras, acquire, check, got 'dance'"),
    ("/api/run", {"kind": "acquire", "name": "/etc"}, 400, "name: expected a plain word"),
    ("/api/run", {"kind": "acquire", "poses": 5}, 400, "poses: expected 12 to"),
])  # fmt: skip
def test_every_bad_request_is_one_line_and_nothing_moves(live, path, body, status, message):
    app = create_app(live, hosts=HOSTS)
    browser = _browser(app)
    browser.post("/api/claim", json={})
    r = browser.post(path, json=body)
    assert r.status_code == status, r.text
    error = r.json()["error"]
    assert message in error
    assert "\n" not in error
    assert live.moves_started == 0


def test_bad_frames_requests_and_a_body_not_json(live):
    browser = _browser(create_app(live, hosts=HOSTS))
    browser.post("/api/claim", json={})
    assert browser.get("/api/frame/top?w=huge").json() == {
        "error": "w: expected a width in px, got 'huge'"
    }
    assert browser.get("/api/frame/top?w=99999").status_code == 400
    r = browser.post("/api/go", content=b"{not json", headers=JSON)
    assert r.status_code == 400
    assert r.json()["error"].startswith("request body: not JSON")
    r = browser.post("/api/go", content=b"[" * 20000, headers=JSON)
    assert r.status_code == 400
    assert r.json() == {"error": "request body: over 16384 bytes"}


def test_a_lost_camera_is_told_in_words_and_the_server_goes_on(live):
    browser = _browser(create_app(live, hosts=HOSTS))
    browser.post("/api/claim", json={})

    def lost():
        raise DeviceError("side: no frame within 2 s (is the camera connected?)")

    live.cameras["side"].inner._grab = lost  # type: ignore[method-assign]
    r = browser.get("/api/frame/side")
    assert r.status_code == 503
    assert r.json() == {"error": "side: no frame within 2 s (is the camera connected?)"}
    assert browser.get("/api/state").json()["camera_errors"] == {"side": r.json()["error"]}
    assert browser.get("/api/frame/top").status_code == 200
    before = live.manipulator.position_um()
    assert browser.post("/api/measure", json={}).status_code == 200
    assert live.wait(30.0)
    assert "no frame within 2 s" in browser.get("/api/state").json()["error"]
    np.testing.assert_allclose(live.manipulator.position_um(), before, atol=0.5)


def test_the_report_is_served_in_an_origin_of_its_own(live, tmp_path):
    browser = _browser(create_app(live, hosts=HOSTS))
    r = browser.get("/report")
    assert r.status_code == 400
    assert r.json() == {"error": "report: there is no report.html beside the calibration"}
    (tmp_path / "report.html").write_text("<h1>report</h1>", encoding="utf-8")
    live.report = tmp_path / "report.html"
    r = browser.get("/report")
    assert r.status_code == 200
    assert r.text == "<h1>report</h1>"
    assert r.headers["content-security-policy"] == "sandbox allow-scripts"
