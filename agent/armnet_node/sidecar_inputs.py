"""The agent's write path into a pod job's connector: operator inputs, the cancel and the preemption.

For a connector in the agent's process the inputs bridge (``node.inputs_bridge``)
hands the cell operator's clicks to a ``LocalOperatorInputs``. A pod job's
connector runs in the pod's sidecar; ``SidecarInputs`` is the same producer
side, delivered over the sidecar's ``agent.sock`` (``connector.agent_inputs``),
which is served in the volume mounted into the connector container only and
reached on the host next to ``observer.sock`` (``node.sidecar_observer``).

Reset waits: the connector numbers each wait; ``watch`` polls ``reset_pending``
while the job runs and calls ``on_reset_requested`` (the bridge's announcement
on ``fms.<cell>.reset.requested``) once per new wait; ``pending_reset_wait``
says whether that wait still waits, as the last poll saw it (the bridge repeats
its notice while it does); a confirmation names the wait announced, so the
connector drops one that arrives after that wait ended.
Verdicts name the rollout the agent saw active; the connector checks again.

Each input is counted by op and result (``armnet_agent_sidecar_inputs_total``);
a failed delivery is logged (rate-limited) and never raises into the bridge.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armnet_connector.agent_inputs import AGENT_SOCKET, MAX_CANCEL_WHY
from armnet_connector.ratelog import RateLimitedLog

from armnet_node.metrics import AgentMetrics
from armnet_node.sidecar_socket import connect_long, exchange

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 2.0
#: How often a running pod job's connector is asked whether a reset waits: the page's prompt lags by at most this.
RESET_POLL_S = 0.5
MAX_REPLY_BYTES = 64 * 1024


def agent_socket(observer_path: Path | None) -> Path | None:
    """``agent.sock`` beside a pod's observer socket (the same connector-only volume)."""
    return observer_path.parent / AGENT_SOCKET if observer_path is not None else None


class SidecarInputs:
    """The producer side of ``OperatorInputs`` for one pod job; every method is safe from any thread."""

    def __init__(self, path: Callable[[], Path | None], metrics: AgentMetrics, *,
                 active_rollout: Callable[[], int | None] | None = None,
                 timeout_s: float = REQUEST_TIMEOUT_S, poll_s: float = RESET_POLL_S) -> None:
        """``path``: where ``agent.sock`` is (None while unknown); ``active_rollout``: the rollout a verdict is for."""
        self._path = path
        self._metrics = metrics
        self._active_rollout = active_rollout
        self._timeout_s = timeout_s
        self._poll_s = poll_s
        #: Called (with this object) once per reset wait the connector began: the bridge announces it.
        self.on_reset_requested: Callable[[SidecarInputs], None] | None = None
        self._announced: int | None = None
        self._pending: int | None = None  # the wait the last answered poll saw waiting, if any
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._watcher: threading.Thread | None = None
        self._problems = RateLimitedLog(log, 60.0)

    # -- what the bridge calls ----------------------------------------------------------

    def set_teleop_action(self, action: dict[str, Any] | None) -> None:
        self._send("teleop_action", {"action": action})

    def push_teleop_event(self, event: str) -> None:
        self._send("teleop_event", {"event": event})

    def report_outcome(self, success: bool) -> bool:
        """False when the connector dropped it (another rollout is active now): the bridge does not record it."""
        rollout = self._active_rollout() if self._active_rollout is not None else None
        return self._send("outcome", {"success": success, "rollout": rollout})

    def request_stop(self) -> None:
        self._send("stop", {})

    def confirm_reset(self) -> bool:
        """Confirm the reset wait announced last; False when none was announced or the connector dropped it."""
        with self._lock:
            wait = self._announced
        if wait is None:
            self._metrics.sidecar_inputs.labels(op="confirm_reset", result="dropped").inc()
            return False
        return self.confirm_reset_wait(wait)

    def confirm_reset_wait(self, wait: int) -> bool:
        """Confirm reset wait ``wait`` only; the connector drops it if another wait is the one waiting."""
        applied = self._send("confirm_reset", {"wait": wait})
        if applied:
            with self._lock:
                if self._pending == wait:
                    self._pending = None  # confirmed: its notice is not repeated while the next poll is due
        return applied

    # -- what the pod session calls -----------------------------------------------------

    def job_started(self) -> bool:
        """Tell the connector the job's container runs: its clock starts now (unless the job's first
        connection started it already)."""
        return self._send("job_started", {})

    def cancel(self, why: str | None = None) -> bool:
        """Open the connector's grace window now (the job's ``is_shutting_down`` turns true), its
        interlock naming ``why`` (default: cancelled)."""
        return self._send("cancel", {} if why is None else {"why": why[:MAX_CANCEL_WHY]})

    def preempt(self, why: str) -> bool | None:
        """Ask the connector to open its grace window at the job's next episode boundary, naming ``why``.

        True: the window is open (the job was between rollouts); False: it opens at the
        end of the open rollout; None: the request did not arrive (counted as failed).
        """
        reply = self._call({"op": "preempt", "why": why[:MAX_CANCEL_WHY]})
        self._metrics.sidecar_inputs.labels(op="preempt", result="failed" if reply is None else "applied").inc()
        return None if reply is None else reply.get("now") is True

    def preempt_window_open(self, why: str) -> bool:
        """Whether the grace window a preemption asked for is open yet (the boundary came).

        Asks with the same op: it changes nothing the second time, and it delivers the
        request should the first one not have arrived. Not counted: a poll, not an input.
        """
        reply = self._call({"op": "preempt", "why": why[:MAX_CANCEL_WHY]})
        return reply is not None and reply.get("now") is True

    def watch(self, running: Callable[[], bool]) -> None:
        """Poll for reset waits in a daemon thread while ``running()`` (the job's container runs), until ``close``."""
        def loop() -> None:
            while not self._closed.wait(self._poll_s):
                if running():
                    self.poll_reset()
                else:
                    with self._lock:
                        self._pending = None  # the job's container is gone: no reset of its waits

        self._watcher = threading.Thread(target=loop, name="armnet-sidecar-inputs", daemon=True)
        self._watcher.start()

    def poll_reset(self) -> None:
        """Ask once whether a reset waits; a new wait is announced (``on_reset_requested``)."""
        reply = self._call({"op": "reset_pending"})
        if reply is None:
            with self._lock:
                self._pending = None  # unknown: stop repeating; the next answered poll resumes it
            return
        wait, pending = reply.get("wait"), reply.get("pending")
        if pending is not True or type(wait) is not int:
            with self._lock:
                self._pending = None
            return
        with self._lock:
            self._pending = wait
            if wait == self._announced:
                return
            self._announced = wait
        callback = self.on_reset_requested
        if callback is not None:
            callback(self)

    def pending_reset_wait(self) -> int | None:
        """The announced reset wait if the last answered poll saw it still waiting, else None."""
        with self._lock:
            return self._pending if self._pending == self._announced else None

    def close(self) -> None:
        self._closed.set()
        if self._watcher is not None:
            self._watcher.join(self._timeout_s + self._poll_s)

    # -- the socket ---------------------------------------------------------------------

    def _send(self, op: str, fields: dict[str, Any]) -> bool:
        """One input; True when the connector applied it. Counted by result, never raises."""
        reply = self._call({"op": op, **fields})
        if reply is None:
            self._metrics.sidecar_inputs.labels(op=op, result="failed").inc()
            return False
        if reply.get("applied") is not True:
            self._metrics.sidecar_inputs.labels(op=op, result="dropped").inc()
            log.warning("the sidecar connector dropped %s: %s", op, str(reply.get("why"))[:200])
            return False
        self._metrics.sidecar_inputs.labels(op=op, result="applied").inc()
        return True

    def _call(self, request: dict[str, Any]) -> dict[str, Any] | None:
        """One request on a fresh connection (inputs are rare; a restarted sidecar is found at once)."""
        path = self._path()
        if path is None:
            self._problems.warning("the sidecar connector's %s is not known yet (no pod uid)", AGENT_SOCKET)
            return None
        deadline = time.monotonic() + self._timeout_s
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(self._timeout_s)
                connect_long(sock, path)
                reply = exchange(sock, request, deadline, MAX_REPLY_BYTES)
        except (OSError, ValueError, RecursionError) as exc:  # RecursionError: JSON nested too deep
            self._problems.warning("the sidecar connector's %s: %s: %s", AGENT_SOCKET, type(exc).__name__, exc)
            return None
        if not isinstance(reply, dict) or reply.get("ok") is not True:
            error = reply.get("error") if isinstance(reply, dict) else None
            self._problems.warning("the sidecar connector refused %s: %s", request["op"], str(error)[:200])
            return None
        return reply
