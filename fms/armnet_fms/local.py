"""The page for one local simulated cell (``armnet run --fms``): the same app, no cluster, no NATS.

``LocalFleet`` shows the local run's cell and job as Cell/RobotJob-shaped
dicts, so ``view`` and ``actions`` work unchanged; ``LocalBus`` hands the
operator's inputs to the run (a callback), and its reset announcements and
telemetry messages (the agent's own ``telemetry.<cell>.*`` payloads) to the
page. ``LocalServer`` serves it on localhost in a thread. Nothing here imports
the agent: the local run passes callables in.
"""

from __future__ import annotations

import asyncio
import json
import logging
import secrets
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from armnet_core.api import CellConditionType, CellPhase, JobPhase
from armnet_core.times import kube_time, micro_time

from .actions import AuditEvent
from .auth import AuthSettings
from .telemetry import TelemetryStore

log = logging.getLogger(__name__)

LOCAL_NAMESPACE = "local"
LOCAL_OPERATOR = "local-operator"


def _now() -> str:
    return kube_time(datetime.now(UTC))


class LocalFleet:
    """One cell, one job; ``rollout()`` reads the connector's latest rollout, ``on_stop`` cancels the run."""

    def __init__(self, cell: str, job_id: str, *, reset_timeout_s: float,
                 rollout: Callable[[], dict[str, int] | None], on_stop: Callable[[], None]) -> None:
        self.cell, self.job_id = cell, job_id
        self.reset_timeout_s = reset_timeout_s
        self._rollout, self._on_stop = rollout, on_stop
        self.phase: str = JobPhase.RUNNING
        self.progress = ""
        self.unschedulable = False
        self.events: list[AuditEvent] = []

    def list_cells(self) -> list[dict[str, Any]]:
        running = self.phase == JobPhase.RUNNING
        return [{
            "metadata": {"name": self.cell, "uid": f"local-{self.cell}", "labels": {}},
            "spec": {"unschedulable": self.unschedulable, "resetTimeoutSeconds": self.reset_timeout_s},
            "status": {"phase": CellPhase.BUSY if running else CellPhase.READY, "lastHeartbeatTime": _now(),
                       "currentJob": f"{LOCAL_NAMESPACE}/{self.job_id}" if running else None,
                       "conditions": [{"type": CellConditionType.INTERLOCK_CLEAR, "status": "True", "reason": "Local"}]},
        }]

    def current_jobs(self, cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
        job = self.get_job(f"{LOCAL_NAMESPACE}/{self.job_id}")
        return [job] if job is not None else []

    def get_cell(self, name: str) -> dict[str, Any] | None:
        return self.list_cells()[0] if name == self.cell else None

    def get_job(self, key: str) -> dict[str, Any] | None:
        if key != f"{LOCAL_NAMESPACE}/{self.job_id}":
            return None
        status: dict[str, Any] = {"phase": self.phase, "jobId": self.job_id, "progress": self.progress}
        rollout = self._rollout()
        if rollout:
            status["rollout"] = rollout
        return {"metadata": {"namespace": LOCAL_NAMESPACE, "name": self.job_id, "uid": self.job_id},
                "status": status}

    def patch_cell(self, name: str, patch: dict[str, Any]) -> None:
        self.unschedulable = bool(patch.get("spec", {}).get("unschedulable", self.unschedulable))

    def patch_job(self, namespace: str, name: str, patch: dict[str, Any]) -> None:
        if patch.get("spec", {}).get("cancel"):
            self._on_stop()

    def post_event(self, event: AuditEvent) -> None:
        self.events.append(event)
        log.warning("%s", event.message)


class LocalBus:
    """``deliver(kind, message)`` applies an input to the run; ``announce_reset()`` may be called from any thread.

    ``notify(subject, data)`` is the run's telemetry publisher (the agent's ``telemetry.<cell>.*``
    messages, exactly as on NATS), handed to ``telemetry`` on the page's own loop: the store is
    read there, so it is written there too. Called from any thread; dropped before the page starts.
    """

    def __init__(self, cell: str, job_id: str, deliver: Callable[[str, dict[str, Any]], None],
                 telemetry: TelemetryStore | None = None) -> None:
        self.cell, self.job_id, self._deliver = cell, job_id, deliver
        self.telemetry = telemetry
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_reset: Callable[[str, dict[str, Any]], None] | None = None

    @property
    def connected(self) -> bool:
        return True

    async def start(self, on_reset_requested: Callable[[str, dict[str, Any]], None]) -> None:
        self._loop, self._on_reset = asyncio.get_running_loop(), on_reset_requested

    async def publish(self, subject: str, data: bytes) -> None:
        kind = subject.removeprefix(f"fms.{self.cell}.")
        self._deliver(kind, json.loads(data))

    async def close(self) -> None:
        self._loop = None

    def notify(self, subject: str, data: bytes) -> None:
        loop, store = self._loop, self.telemetry
        if loop is not None and store is not None:
            loop.call_soon_threadsafe(store.accept, subject, data, time.time())

    def announce_reset(self, *_: Any) -> None:
        at = micro_time(datetime.now(UTC))
        notice = {"namespace": LOCAL_NAMESPACE, "job": self.job_id, "at": at, "request": f"{self.job_id}@{at}"}
        loop, callback = self._loop, self._on_reset
        if loop is not None and callback is not None:
            loop.call_soon_threadsafe(callback, self.cell, notice)


class LocalServer:
    """The app on 127.0.0.1:<port> in a daemon thread, with a one-run login token."""

    def __init__(self, fleet: LocalFleet, bus: LocalBus, port: int) -> None:
        import uvicorn

        from .app import build_app
        from .state import FleetState

        self.token = secrets.token_urlsafe(18)
        self.url = f"http://127.0.0.1:{port}"
        settings = AuthSettings(secret_key=secrets.token_bytes(32), tokens={self.token: LOCAL_OPERATOR})
        self.state = FleetState(fleet, poll_s=0.5)
        app = build_app(self.state, bus, settings, secure_cookies=False, telemetry=bus.telemetry)
        self._server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning",
                                                     access_log=False))
        self._thread = threading.Thread(target=self._server.run, name="armnet-fms", daemon=True)

    def start(self, timeout_s: float = 20) -> LocalServer:
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while not self._server.started:
            if time.monotonic() > deadline or not self._thread.is_alive():
                raise RuntimeError(f"the cell operator's page did not start on {self.url}")
            time.sleep(0.05)
        return self

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(10)
