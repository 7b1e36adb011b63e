"""The station page's web application (Starlette): the page, its API, and who may use it.

Every answer to a bad request is one line: ``{"error": "..."}`` with status 400 (bad
input), 403 (refused: no token, another site, a watching browser), 409 (a target outside the
limits, a move under way) or 503 (a camera or device that failed); the server keeps running.
The routes (all under the token when there is one):

=========================  =================================================================
``GET /``                  the page
``GET /api/layout``        cameras, target kind, device, limits (:meth:`LiveStation.layout`)
``GET /api/state``         device, activity, target, arrival, errors; renews the lease
``GET /api/overlays``      per camera: predicted and measured tip, target, soft limits
``GET /api/frame/CAM``     a JPEG of the camera, ``?w=640`` px wide
``GET /api/zoom/CAM``      a full-resolution region, ``?x=&y=&size=``
``GET /report``            the latest report.html beside the calibration (sandboxed)
``POST /api/claim``        take control if nobody has it
``POST /api/epipolar``     ``{"camera", "x_px", "y_px"}``: the click's curves in the others
``POST /api/target``       ``{"clicks": {CAM: [x, y]}, "std_px": {CAM: s}, "first", "offset_um"}``:
                           the 3D target; the clicks after the ``first`` camera's are taken
                           onto its epipolar line (or the target found along it); one
                           camera: one click, the focal plane + the offset
``POST /api/focal-plane``  one camera: the focal plane through the tip now
``POST /api/go``           ``{"target_um", "mode", "tolerance_um"}``
``POST /api/measure``      measure the tip now
``POST /api/stop``         stop now (any browser); a run under way is cancelled too
``POST /api/run``          ``{"kind", "name", "poses", "resume"}``: start a run
``POST /api/run/cancel``   cancel the run under way after its current step
=========================  =================================================================
"""

from __future__ import annotations

import json
import math
import secrets
from collections.abc import Awaitable, Callable
from importlib import resources
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.middleware.base import BaseHTTPMiddleware, RequestResponseEndpoint
from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ..errors import DeviceError, InputError, LimitError, MicrocalError
from ..workflows.live import LiveStation
from ..workflows.live_runs import StationRuns
from .access import CLIENT_COOKIE, TOKEN_COOKIE, Control, token_matches

__all__ = ["MAX_BODY_BYTES", "create_app"]

#: The largest request body accepted, bytes.
MAX_BODY_BYTES = 16384
_STATIC = resources.files("microcal.ui") / "static"


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


def _status_of(exc: MicrocalError) -> int:
    if isinstance(exc, LimitError):
        return 409
    if isinstance(exc, DeviceError):
        return 503
    if isinstance(exc, InputError) and str(exc).startswith("busy:"):
        return 409
    return 400


class _Guard(BaseHTTPMiddleware):
    """The token, the Host and Origin checks (see :mod:`microcal.ui.access`)."""

    def __init__(self, app: Any, token: str | None, hosts: frozenset[str]) -> None:
        super().__init__(app)
        self.token = token
        self.hosts = hosts

    async def dispatch(self, request: Request, call_next: RequestResponseEndpoint) -> Response:
        host = request.headers.get("host", "")
        if self.hosts and host not in self.hosts:
            return _error(
                403,
                f"refused: this station answers to {', '.join(sorted(self.hosts))}, not {host!r}",
            )
        from_query = request.query_params.get("token")
        if self.token is not None and not (
            token_matches(from_query, self.token)
            or token_matches(request.cookies.get(TOKEN_COOKIE), self.token)
        ):
            return _error(
                403, "refused: this station needs its token in the URL (printed when it started)"
            )
        if request.method == "POST":
            origin = request.headers.get("origin")
            if origin is not None and origin not in {f"http://{host}", f"https://{host}"}:
                return _error(403, f"refused: a request from another site ({origin})")
            if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
                return _error(400, "expected a JSON body (Content-Type: application/json)")
        response = await call_next(request)
        if self.token is not None and token_matches(from_query, self.token):
            response.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite="strict")
        return response


def _number(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{what}: expected a finite number, got {value!r}")
    return float(value)


def _point(value: object, what: str, n: int) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise InputError(f"{what}: expected a list of {n} numbers, got {value!r}"[:200])
    return [_number(v, what) for v in value]


def create_app(
    live: LiveStation,
    token: str | None = None,
    hosts: frozenset[str] = frozenset(),
    control: Control | None = None,
    runs: StationRuns | None = None,
) -> Starlette:
    """The station page's application around an opened :class:`LiveStation`.

    Parameters
    ----------
    live : LiveStation
    token : str, optional
        Required in every request (the URL, then a cookie) when given.
    hosts : set of str
        The ``Host`` values this server answers to (``127.0.0.1:8765``...); empty: any.
    control : Control, optional
        The controlling browser's lease (a fresh one by default).
    runs : StationRuns, optional
        The runs the page starts (by default on ``live``, writing beside its calibration;
        none when the station was opened without the calibration's path).
    """
    lease = control or Control()
    if runs is None and live.calibration_path is not None:
        runs = StationRuns(live)

    def client_of(request: Request) -> str | None:
        return request.cookies.get(CLIENT_COOKIE)

    async def body(request: Request) -> dict[str, Any]:
        raw = await request.body()
        if len(raw) > MAX_BODY_BYTES:
            raise InputError(f"request body: over {MAX_BODY_BYTES} bytes")
        try:
            data = json.loads(raw or b"{}")
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(
                f"request body: not JSON ({exc.msg if hasattr(exc, 'msg') else exc})"
            ) from None
        if not isinstance(data, dict):
            raise InputError("request body: expected a JSON object")
        return data

    Handler = Callable[[Request], Awaitable[Response]]

    def guarded(handler: Handler, controlling: bool = False) -> Handler:
        async def run(request: Request) -> Response:
            if controlling and not lease.controls(client_of(request)):
                return _error(
                    403, "refused: another browser controls this station; this one watches"
                )
            try:
                return await handler(request)
            except MicrocalError as exc:
                return _error(_status_of(exc), str(exc))

        return run

    async def page(request: Request) -> Response:
        html = (_STATIC / "index.html").read_text(encoding="utf-8")
        response = HTMLResponse(html, headers={"Cache-Control": "no-store"})
        if client_of(request) is None:
            response.set_cookie(
                CLIENT_COOKIE, secrets.token_urlsafe(16), httponly=True, samesite="strict"
            )
        return response

    def role(request: Request) -> str:
        return "control" if lease.renew(client_of(request) or "") else "watch"

    async def layout(request: Request) -> Response:
        return JSONResponse(live.layout() | {"role": role(request)})

    async def state(request: Request) -> Response:
        out = await run_in_threadpool(live.state)
        run_state = runs.state() if runs is not None else None
        extra = {"role": role(request), "controlled": lease.held(), "run": run_state}
        return JSONResponse(out | extra | {"health": live.health})

    async def overlays(request: Request) -> Response:
        return JSONResponse(await run_in_threadpool(live.overlays))

    async def frame(request: Request) -> Response:
        camera = request.path_params["camera"]
        width = request.query_params.get("w", "640")
        if not width.isdigit():
            raise InputError(f"w: expected a width in px, got {width!r}"[:200])
        data = await run_in_threadpool(live.frame_jpeg, camera, int(width))
        return Response(data, media_type="image/jpeg", headers={"Cache-Control": "no-store"})

    async def zoom(request: Request) -> Response:
        camera = request.path_params["camera"]
        q = request.query_params
        try:
            x, y, size = (
                int(float(q.get(k, d))) for k, d in (("x", "0"), ("y", "0"), ("size", "160"))
            )
        except ValueError:
            raise InputError("zoom: expected x, y and size as numbers of px") from None
        data = await run_in_threadpool(live.frame_jpeg, camera, 640, (x, y, size))
        return Response(data, media_type="image/jpeg", headers={"Cache-Control": "no-store"})

    async def report(request: Request) -> Response:
        data = await run_in_threadpool(live.report_html)
        # its own opaque origin: nothing in the report can use this page's controls
        return HTMLResponse(data, headers={"Content-Security-Policy": "sandbox allow-scripts"})

    async def claim(request: Request) -> Response:
        client = client_of(request)
        if client is None:
            raise InputError("claim: this browser has no session; load the page first")
        return JSONResponse({"role": "control" if lease.claim(client) else "watch"})

    async def epipolar(request: Request) -> Response:
        data = await body(request)
        q = [_number(data.get("x_px"), "x_px"), _number(data.get("y_px"), "y_px")]
        return JSONResponse({"curves": live.epipolar(str(data.get("camera")), q)})

    async def target(request: Request) -> Response:
        data = await body(request)
        clicks, std = data.get("clicks"), data.get("std_px", {})
        if not isinstance(clicks, dict) or not isinstance(std, dict):
            raise InputError(
                'target: expected {"clicks": {camera: [x, y]}, "std_px": {camera: px}}'
            )
        points = {str(k): _point(v, f"click in {k}", 2) for k, v in clicks.items()}
        stds = {str(k): _number(v, f"std_px of {k}") for k, v in std.items()}
        if any(not s > 0 for s in stds.values()):
            raise InputError("std_px: expected numbers of px > 0")
        offset = _number(data.get("offset_um", 0.0), "offset_um")
        first = data.get("first")
        if first is not None and not isinstance(first, str):
            raise InputError(f"first: expected a camera's name, got {first!r}"[:200])
        result = await run_in_threadpool(live.target_from_clicks, points, stds, offset, first)
        return JSONResponse(result.as_dict())

    async def focal_plane(request: Request) -> Response:
        return JSONResponse(await run_in_threadpool(live.set_focal_plane))

    async def go(request: Request) -> Response:
        data = await body(request)
        p = _point(data.get("target_um"), "target_um", 3)
        mode = data.get("mode", "closed")
        tol = data.get("tolerance_um")
        tolerance = None if tol is None else _number(tol, "tolerance_um")
        await run_in_threadpool(live.go, p, mode, tolerance)
        return JSONResponse({"started": True})

    async def measure(request: Request) -> Response:
        await run_in_threadpool(live.measure)
        return JSONResponse({"started": True})

    async def stop(request: Request) -> Response:
        if runs is not None:
            runs.cancel()
        await run_in_threadpool(live.stop)
        return JSONResponse({"stopped": True})

    def the_runs() -> StationRuns:
        if runs is None:
            raise InputError("runs: this station was opened without its calibration's path")
        return runs

    async def run_start(request: Request) -> Response:
        data = await body(request)
        kind = data.pop("kind", None)
        started = await run_in_threadpool(the_runs().start, str(kind), data)
        return JSONResponse({"started": started.kind})

    async def run_cancel(request: Request) -> Response:
        return JSONResponse({"cancelling": the_runs().cancel()})

    routes = [
        Route("/", guarded(page)),
        Route("/api/layout", guarded(layout)),
        Route("/api/state", guarded(state)),
        Route("/api/overlays", guarded(overlays)),
        Route("/api/frame/{camera}", guarded(frame)),
        Route("/api/zoom/{camera}", guarded(zoom)),
        Route("/report", guarded(report)),
        Route("/api/claim", guarded(claim), methods=["POST"]),
        Route("/api/epipolar", guarded(epipolar), methods=["POST"]),
        Route("/api/target", guarded(target, controlling=True), methods=["POST"]),
        Route("/api/go", guarded(go, controlling=True), methods=["POST"]),
        Route("/api/focal-plane", guarded(focal_plane, controlling=True), methods=["POST"]),
        Route("/api/measure", guarded(measure, controlling=True), methods=["POST"]),
        Route("/api/stop", guarded(stop), methods=["POST"]),
        Route("/api/run", guarded(run_start, controlling=True), methods=["POST"]),
        Route("/api/run/cancel", guarded(run_cancel, controlling=True), methods=["POST"]),
        Mount("/static", StaticFiles(directory=str(_STATIC)), name="static"),
    ]
    return Starlette(routes=routes, middleware=[Middleware(_Guard, token=token, hosts=hosts)])
