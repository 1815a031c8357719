"""The FMS web service (Starlette): pages, the live feed (server-sent events), the actions.

Every path but ``/login``, ``/logout``, ``/healthz``, ``/metrics`` and the
static files (``PUBLIC_PATHS``) needs an authenticated cell operator (the
``guard.CellOperatorsOnly`` middleware; a route reads who with ``guard.caller_of``);
every response carries the security headers (the ``guard.SecurityHeaders``
middleware). A POST made with a session
cookie or a proxy header must carry that credential's CSRF token. Decisions
live in ``view`` and ``actions``; this module reads requests, applies plans and
counts them.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import json
import logging
import re
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, generate_latest
from prometheus_client.core import CounterMetricFamily
from prometheus_client.exposition import CONTENT_TYPE_LATEST
from prometheus_client.registry import Collector
from starlette.applications import Starlette
from starlette.concurrency import iterate_in_threadpool
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import (
    HTMLResponse,
    JSONResponse,
    PlainTextResponse,
    RedirectResponse,
    Response,
    StreamingResponse,
)
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from . import auth
from .actions import ActionKind, Plan, Refused, plan_action
from .bus import BusUnavailable, OperatorBus
from .cell_video import CellVideos
from .guard import SESSION_COOKIE, CellOperatorsOnly, SecurityHeaders, caller_of
from .state import FleetState
from .telemetry import TelemetryStore
from .view import build_row, row_json

log = logging.getLogger(__name__)

#: The paths anyone may reach (and ``/static/``): logging in and out, metrics, health.
PUBLIC_PATHS = frozenset({"/login", "/logout", "/metrics", "/healthz"})

STATIC = Path(__file__).parent / "static"
#: A download's file name: the job's and camera's names, in letters every browser keeps.
_SAFE_FILE = re.compile(r"[^A-Za-z0-9._-]")


class Metrics:
    """The FMS's metrics, in a registry of its own (no module-level state)."""

    def __init__(self, state: FleetState, bus: OperatorBus) -> None:
        self.registry = CollectorRegistry()
        self.actions = Counter("armnet_fms_actions", "Cell operator actions by action and result",
                               ["action", "result"], registry=self.registry)
        self.logins = Counter("armnet_fms_logins", "Login attempts by result", ["result"], registry=self.registry)
        self.videos = Counter("armnet_fms_last_video_requests", "Requests for a cell's last job's video by result "
                              "(served, none: no stored job or video, store_error)", ["result"], registry=self.registry)
        self.live_clients = Gauge("armnet_fms_live_clients", "Pages following the live feed",
                                  registry=self.registry)
        Gauge("armnet_fms_pending_resets", "Resets waiting for a cell operator's confirmation",
              registry=self.registry).set_function(lambda: len(state.pending))
        Gauge("armnet_fms_kube_ok", "1 when the last read of the Kubernetes API worked",
              registry=self.registry).set_function(lambda: 1.0 if state.kube_ok else 0.0)
        Gauge("armnet_fms_nats_connected", "1 when NATS is connected", registry=self.registry
              ).set_function(lambda: 1.0 if bus.connected else 0.0)


class TelemetryCollector(Collector):
    """The telemetry store's counts, read at scrape time (the store stays free of metrics)."""

    def __init__(self, store: TelemetryStore) -> None:
        self._store = store

    def collect(self) -> Any:
        family = CounterMetricFamily("armnet_fms_telemetry_messages", "Agents' telemetry messages (frames, "
                                     "servo readings) kept, refused (bad subject, unknown cell, not JPEG, too "
                                     "large) or dropped (the FMS fell behind a flood)",
                                     labels=["result"])
        family.add_metric(["kept"], self._store.kept)
        family.add_metric(["refused"], self._store.refused)
        family.add_metric(["dropped"], self._store.dropped)
        yield family


def _page(name: str, **values: str) -> HTMLResponse:
    text = (STATIC / name).read_text(encoding="utf-8")
    for key, value in values.items():
        text = text.replace("{{" + key + "}}", html.escape(value, quote=True))
    return HTMLResponse(text)


def build_app(state: FleetState, bus: OperatorBus, settings: auth.AuthSettings, *, site: str = "",
              secure_cookies: bool = True, live_interval_s: float = 0.5,
              clock: Callable[[], float] = time.time, telemetry: TelemetryStore | None = None,
              videos: CellVideos | None = None) -> Starlette:
    """The Starlette app; its lifespan starts the NATS subscription and the poller.

    ``telemetry`` is filled by the bus (``Bus(on_telemetry=...)``); without one (a local run) the
    cell page has no camera or servo section and polls nothing. ``videos`` reads the last job's
    video of a cell from the object store; without one the cell page offers none.
    """
    metrics = Metrics(state, bus)
    store = telemetry if telemetry is not None else TelemetryStore()
    metrics.registry.register(TelemetryCollector(store))
    Gauge("armnet_fms_telemetry_frames_held", "Latest camera frames held (one per cell and camera)",
          registry=metrics.registry).set_function(lambda: store.frames_held)
    Gauge("armnet_fms_telemetry_frame_bytes", "Bytes of all latest camera frames held (bounded by the frame budget)",
          registry=metrics.registry).set_function(lambda: store.frame_bytes)

    async def login_page(request: Request) -> Response:
        return _page("login.html", message="")

    async def login(request: Request) -> Response:
        form = await request.form()
        operator = auth.operator_for_token(settings, str(form.get("token", "")))
        if operator is None:
            metrics.logins.labels("refused").inc()
            refused = _page("login.html", message="That token is not a cell operator's token.")
            refused.status_code = 401
            return refused
        metrics.logins.labels("ok").inc()
        response = RedirectResponse("/", status_code=303)
        response.set_cookie(SESSION_COOKIE, auth.make_session(settings, operator, clock()),
                            max_age=settings.session_ttl_s, httponly=True, samesite="strict",
                            secure=secure_cookies, path="/")
        return response

    async def logout(request: Request) -> Response:
        response = RedirectResponse("/login", status_code=303)
        response.delete_cookie(SESSION_COOKIE, path="/")
        return response

    async def fleet_page(request: Request) -> Response:
        who = caller_of(request)
        return _page("fleet.html", operator=who.operator, csrf=auth.csrf_token(settings, who.credential))

    async def cell_page(request: Request) -> Response:
        who = caller_of(request)
        return _page("cell.html", operator=who.operator, csrf=auth.csrf_token(settings, who.credential),
                     cell=request.path_params["name"], telemetry="on" if telemetry is not None else "off",
                     video="on" if videos is not None else "off")

    def snapshot(request: Request) -> dict[str, Any]:
        now = clock()
        rows = state.rows(site=request.query_params.get("site", site), query=request.query_params.get("q", ""))
        only = request.query_params.get("cell")
        if only:
            rows = [r for r in rows if r.name == only]
        return {"cells": [row_json(r, now) for r in rows], "kubeOk": state.kube_ok, "natsOk": bus.connected}

    async def fleet_json(request: Request) -> Response:
        return JSONResponse(snapshot(request))

    async def live(request: Request) -> Response:
        async def events() -> AsyncIterator[bytes]:
            metrics.live_clients.inc()
            last, quiet = "", 0.0
            try:
                while not await request.is_disconnected():
                    data = json.dumps(snapshot(request), separators=(",", ":"))
                    if data != last:
                        last, quiet = data, 0.0
                        yield f"data: {data}\n\n".encode()
                    elif quiet > 15:
                        quiet = 0.0
                        yield b": keep-alive\n\n"
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(state.changed.wait(), live_interval_s)
                    state.changed.clear()
                    quiet += live_interval_s
            finally:
                metrics.live_clients.dec()

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"X-Accel-Buffering": "no"})

    async def camera_frame(request: Request) -> Response:
        frame = store.frame(request.path_params["name"], request.path_params["camera"])
        if frame is None:
            return JSONResponse({"error": "no frame from this camera yet"}, status_code=404)
        return Response(frame.jpeg, media_type="image/jpeg")

    async def last_video(request: Request) -> Response:
        cell = request.path_params["name"]
        if videos is None:
            return JSONResponse({"error": "this FMS reads no object store (the chart's artifacts.*: docs/fms.md)"},
                                status_code=404)
        try:
            found = await asyncio.to_thread(videos.open_last, cell, request.query_params.get("camera") or None)
        except Exception as error:  # noqa: BLE001 - botocore's and the API's errors: the operator sees why
            metrics.videos.labels("store_error").inc()
            log.warning("cell %s: the last job's video could not be read: %s", cell, str(error)[:300])
            return JSONResponse({"error": f"the object store could not be read ({type(error).__name__}); "
                                          "the FMS's log says more"}, status_code=502)
        if isinstance(found, str):
            metrics.videos.labels("none").inc()
            return JSONResponse({"error": found}, status_code=404)
        metrics.videos.labels("served").inc()
        name = _SAFE_FILE.sub("_", f"{found.job.name}-{found.camera}")
        headers = {"Content-Disposition": f'inline; filename="{name}.mp4"',
                   "X-Armnet-Job": f"{found.job.namespace}/{found.job.name}", "Cache-Control": "no-store"}
        if found.length is not None:
            headers["Content-Length"] = str(found.length)
        return StreamingResponse(iterate_in_threadpool(found.chunks), media_type="video/mp4", headers=headers)

    async def cell_telemetry(request: Request) -> Response:
        return JSONResponse(store.view(request.path_params["name"], clock()))

    async def act(request: Request) -> Response:
        who = caller_of(request)
        try:
            kind = ActionKind(request.path_params["action"])
        except ValueError:
            return JSONResponse({"error": "unknown action"}, status_code=404)
        if who.credential and not auth.csrf_ok(settings, who.credential, request.headers.get("x-csrf-token", "")):
            metrics.actions.labels(kind.value, "csrf_refused").inc()
            return JSONResponse({"error": "missing or wrong CSRF token; reload the page"}, status_code=403)
        body = await _json_body(request)
        name = request.path_params["name"]
        try:
            plan, target = await _decide(kind, name, who.operator, str(body.get("request", ""))[:128])
            await _apply(plan, target)
        except Refused as refusal:
            metrics.actions.labels(kind.value, "refused").inc()
            return JSONResponse({"error": str(refusal)}, status_code=409)
        except BusUnavailable as error:
            metrics.actions.labels(kind.value, "error").inc()
            return JSONResponse({"error": str(error)}, status_code=503)
        metrics.actions.labels(kind.value, "ok").inc()
        log.info("cell %s: %s by cell operator %s", name, plan.done, who.operator)
        state.refresh_soon()
        return JSONResponse({"ok": True, "message": plan.done})

    async def _decide(kind: ActionKind, name: str, operator: str, request_id: str) -> tuple[Plan, str]:
        # Re-read the cell and its job: the button the operator pressed may be older than the fleet.
        cell = await asyncio.to_thread(state.kube.get_cell, name)
        if cell is None:
            raise Refused(f"there is no cell {name[:60]!r}")
        key = (cell.get("status") or {}).get("currentJob")
        job = await asyncio.to_thread(state.kube.get_job, key) if isinstance(key, str) else None
        row = build_row(cell, {key: job} if job is not None and isinstance(key, str) else {},
                        state.pending.get(name), clock())
        uid = str((cell.get("metadata") or {}).get("uid", ""))
        return plan_action(kind, row, operator, clock(), request=request_id, cell_uid=uid), name

    async def _apply(plan: Plan, cell: str) -> None:
        for subject, data in plan.messages:
            await bus.publish(subject, data)
        if plan.confirmed_request:
            state.clear_reset(cell, plan.confirmed_request)
        if plan.cell_spec_patch is not None:
            await asyncio.to_thread(state.kube.patch_cell, cell, plan.cell_spec_patch)
        if plan.job_patch is not None:
            await asyncio.to_thread(state.kube.patch_job, *plan.job_patch)
        if plan.event is not None:
            try:
                await asyncio.to_thread(state.kube.post_event, plan.event)
            except Exception as error:  # noqa: BLE001 - the action happened; a lost audit Event is logged
                log.error("audit event %s for %s not posted: %s", plan.event.reason, plan.event.name, error)

    async def metrics_route(request: Request) -> Response:
        return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)

    async def healthz(request: Request) -> Response:
        return PlainTextResponse("ok" if state.kube_ok else "kubernetes API unreachable",
                                 status_code=200 if state.kube_ok else 503)

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        await bus.start(state.on_reset_requested)
        await state.refresh()
        poller = asyncio.create_task(state.poll_forever())
        try:
            yield
        finally:
            poller.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await poller
            await bus.close()

    # The only paths anyone may reach (``PUBLIC_PATHS``, ``/static/``); ``CellOperatorsOnly`` refuses
    # every other request that is not a cell operator's, whatever route it asks for.
    routes = [
        Route("/login", login_page, methods=["GET"]),
        Route("/login", login, methods=["POST"]),
        Route("/logout", logout, methods=["POST"]),
        Route("/metrics", metrics_route),
        Route("/healthz", healthz),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
        Route("/", fleet_page),
        Route("/cells/{name}", cell_page),
        Route("/api/fleet", fleet_json),
        Route("/live", live),
        Route("/api/cells/{name}/camera/{camera}.jpg", camera_frame, methods=["GET"]),
        Route("/api/cells/{name}/telemetry", cell_telemetry, methods=["GET"]),
        Route("/api/cells/{name}/last-video.mp4", last_video, methods=["GET"]),
        Route("/api/cells/{name}/{action}", act, methods=["POST"]),
    ]
    app = Starlette(routes=routes, lifespan=lifespan, middleware=[
        Middleware(SecurityHeaders),
        Middleware(CellOperatorsOnly, settings=settings, clock=clock, public=PUBLIC_PATHS,
                   public_prefixes=("/static/",), routes=routes),
    ])
    app.state.metrics = metrics
    return app


async def _json_body(request: Request) -> dict[str, Any]:
    raw = await request.body()
    if not raw or len(raw) > 4096:
        return {}
    try:
        body = json.loads(raw)
    except ValueError:
        return {}
    return body if isinstance(body, dict) else {}
