"""The agent's view of a pod job's connector: its observer socket, reached on the host.

A pod job's connector runs in the pod's sidecar, where the agent cannot call
into it. It serves a read-only ``observer.sock`` (``connector.observer``) in an
``emptyDir`` mounted into the sidecar only; the kubelet keeps that volume on
the host at ``<kubelet root>/pods/<pod uid>/volumes/kubernetes.io~empty-dir/observer/``,
where the agent (root on the host, or the DaemonSet with the kubelet's pods
directory mounted read-only with ``HostToContainer`` propagation) connects.

``SidecarObserver`` gives the same two things as a connector in the agent's
process, so one path serves both launchers: a ``JobView`` (servo positions of
the job's reads, frames of the cameras it opened, the completion monitor's verdict
now) for ``JobSource``, and the connector's rollout events for the ``RolloutRecorder``.

Why this cannot be forged by the tenant: the customer container mounts neither
this volume nor the host directory; sharing the pod's network namespace gives
no path to a filesystem socket. Everything read is still checked before use.

Restarts: a restarted sidecar serves the socket anew in the same volume (the
next request reconnects); a restarted agent finds it again from the pod's uid.
Each failed connection is counted (``armnet_agent_sidecar_observer_requests_total``)
and retried at most once a second.
"""

from __future__ import annotations

import base64
import logging
import math
import re
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from armnet_connector.cell import MAX_ROLLOUT_EVENTS, RolloutEvent
from armnet_connector.inputs import MonitorVerdict
from armnet_connector.observer import OBSERVER_SOCKET
from armnet_connector.ratelog import RateLimitedLog
from armnet_connector.telemetry import CameraFrame
from armnet_connector.telemetry_decode import ServoSample
from armnet_launch.pod_spec import OBSERVER_VOLUME

from armnet_node.metrics import AgentMetrics
from armnet_node.sidecar_socket import connect_long, exchange
from armnet_node.telemetry_wire import MAX_CAMERAS

log = logging.getLogger(__name__)

DEFAULT_KUBELET_ROOT = Path("/var/lib/kubelet")
#: A reply is at most a few frames of at most 640 px wide (``connector.observer``): far below this.
MAX_REPLY_BYTES = 32 << 20
REQUEST_TIMEOUT_S = 2.0
RETRY_S = 1.0
"""After a failed request the socket is left alone this long. Not a retry loop (no backoff): the
callers ask at their own cadence (telemetry ticks, rollout syncs); this only spares a dead socket."""
#: Pages of rollout events asked for in one sync at most (256 each): the connector keeps 1024.
MAX_EVENT_PAGES = 4
_POD_UID = re.compile(r"^[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}$")
_MAX_PIXELS = 640 * 640 * 3


def observer_socket(kubelet_root: Path, pod_uid: str) -> Path | None:
    """Where the kubelet keeps a pod's observer socket on the host; None for a uid that is not one."""
    if not _POD_UID.match(pod_uid):
        return None
    return kubelet_root / "pods" / pod_uid / "volumes" / "kubernetes.io~empty-dir" / OBSERVER_VOLUME / OBSERVER_SOCKET


def parse_servos(data: Any) -> dict[str, Mapping[str, ServoSample | None] | str] | None:
    """The observer's ``servos`` reply as ``job_servos`` gives it; ValueError when it is not that shape."""
    if data is None:
        return None
    if not isinstance(data, dict):
        raise ValueError("servos is not an object")
    readings: dict[str, Mapping[str, ServoSample | None] | str] = {}
    for arm, motors in data.items():
        if isinstance(motors, str):
            readings[str(arm)] = motors[:200]
            continue
        if not isinstance(motors, dict):
            raise ValueError(f"arm {str(arm)[:32]!r} is neither readings nor a reason")
        samples: dict[str, ServoSample | None] = {}
        for motor, value in motors.items():
            if value is None:
                samples[str(motor)] = None
                continue
            if not (isinstance(value, list) and len(value) == 3 and all(
                    v is None or (type(v) is int) for v in value) and value[0] is not None):
                raise ValueError(f"motor {str(motor)[:32]!r} is not [position, load, temperature]")
            samples[str(motor)] = ServoSample(value[0], value[1], value[2])
        readings[str(arm)] = samples
    return readings


def parse_frame(data: Any) -> CameraFrame:
    """One frame of the observer's ``frames`` reply; ValueError when it is not an HxWx3 uint8 picture."""
    import numpy as np

    if not isinstance(data, dict) or data.get("dtype") != "uint8" or not isinstance(data.get("data"), str):
        raise ValueError("a frame is an object with dtype uint8 and base64 data")
    shape = data.get("shape")
    if not (isinstance(shape, list) and len(shape) == 3 and all(type(n) is int and n > 0 for n in shape)
            and shape[2] == 3 and shape[0] * shape[1] * 3 <= _MAX_PIXELS):
        raise ValueError(f"a frame is HxWx3 of at most {_MAX_PIXELS} values, got shape {str(shape)[:64]}")
    pixels = base64.b64decode(data["data"], validate=True)
    if len(pixels) != shape[0] * shape[1] * 3:
        raise ValueError("a frame's data does not match its shape")
    return CameraFrame(np.frombuffer(pixels, dtype=np.uint8).reshape(shape), bgr=data.get("bgr") is True)


def parse_monitor(data: Any) -> MonitorVerdict | None:
    """The observer's ``monitor`` reply's verdict (None: the cell scores nothing); ValueError when it is not one."""
    if data is None:
        return None
    if not isinstance(data, dict) or not isinstance(data.get("complete"), bool):
        raise ValueError("a monitor verdict is an object with a boolean complete")
    score, frame_at = data.get("score"), data.get("frame_at")
    for name, value in (("score", score), ("frame_at", frame_at)):
        if value is not None and not _finite(value):
            raise ValueError(f"a monitor verdict's {name} is a finite number")
    if score is None:
        raise ValueError("a monitor verdict has a score")
    return MonitorVerdict(data["complete"], float(score), None if frame_at is None else float(frame_at))


def _finite(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)


def parse_event(data: Any) -> RolloutEvent:
    """One rollout event of the observer's ``rollouts`` reply; ValueError when it is not one."""
    if not isinstance(data, dict) or data.get("kind") not in ("begin", "end", "verdict"):
        raise ValueError("a rollout event is an object of kind begin, end or verdict")
    at = data.get("at")
    if isinstance(at, bool) or not isinstance(at, int | float):
        raise ValueError("a rollout event's time is a number")
    index, total, controls = data.get("index"), data.get("total"), data.get("outcome_controls")
    for name, value in (("index", index), ("total", total)):
        if value is not None and type(value) is not int:
            raise ValueError(f"a rollout event's {name} is an integer")
    if controls is not None and not isinstance(controls, bool):
        raise ValueError("a rollout event's outcome_controls is a boolean")
    success, score, frame_at = data.get("success"), data.get("score"), data.get("frame_at")
    if success is not None and not isinstance(success, bool):
        raise ValueError("a rollout event's success is a boolean")
    for name, value in (("score", score), ("frame_at", frame_at)):
        if value is not None and not _finite(value):
            raise ValueError(f"a rollout event's {name} is a finite number")
    return RolloutEvent(data["kind"], float(at), index, total, controls, success,
                        None if score is None else float(score), None if frame_at is None else float(frame_at))


class SidecarObserver:
    """One pod job's connector seen through its observer socket; every method is safe from any thread.

    ``path()`` says where the socket is (None while the pod's uid is unknown).
    ``servos``/``frames`` make it a ``JobView``; ``rollout_events`` is the
    connector's events as a connector in this process would give them (the same
    objects on every call: the recorder recognises what it has seen).
    """

    def __init__(self, path: Callable[[], Path | None], metrics: AgentMetrics, *,
                 timeout_s: float = REQUEST_TIMEOUT_S, retry_s: float = RETRY_S) -> None:
        self._path = path
        self._metrics = metrics
        self._timeout_s = timeout_s
        self._retry_s = retry_s
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._retry_at = 0.0
        self._events: deque[RolloutEvent] = deque(maxlen=MAX_ROLLOUT_EVENTS)
        self._events_lock = threading.Lock()
        self._problems = RateLimitedLog(log, 60.0)
        #: The connector serves no ``monitor`` op (its image predates it): the page shows no live verdict.
        self._monitor_unknown = False

    # -- JobView --------------------------------------------------------------------------

    def servos(self) -> Mapping[str, Mapping[str, ServoSample | None] | str] | None:
        reply = self._call({"op": "servos"})
        if reply is None:
            return None
        try:
            return parse_servos(reply.get("servos"))
        except ValueError as exc:
            self._count("invalid", f"servos: {exc}")
            return None

    def monitor(self) -> MonitorVerdict | None:
        if self._monitor_unknown:
            return None
        reply = self._call({"op": "monitor"})
        if reply is None:
            return None
        try:
            return parse_monitor(reply.get("monitor"))
        except ValueError as exc:
            self._count("invalid", f"monitor: {exc}")
            return None

    def frames(self) -> Mapping[str, CameraFrame]:
        reply = self._call({"op": "frames"})
        frames = reply.get("frames") if reply is not None else None
        if not isinstance(frames, dict):
            return {}
        parsed: dict[str, CameraFrame] = {}
        for name, data in list(frames.items())[:MAX_CAMERAS]:
            try:
                parsed[str(name)] = parse_frame(data)
            except ValueError as exc:
                self._count("invalid", f"frame of {str(name)[:32]}: {exc}")
        return parsed

    # -- rollout events -----------------------------------------------------------------------

    def rollout_events(self) -> list[RolloutEvent]:
        """The connector's events so far (the observer's new ones appended), oldest first.

        The socket is asked without holding the events' lock: ``take_events`` (the
        job's end) never waits for a slow or stalling peer.
        """
        for _ in range(MAX_EVENT_PAGES):
            with self._events_lock:
                after = self._events[-1].at if self._events else None
            reply = self._call({"op": "rollouts", "after": after})
            if reply is None or not isinstance(reply.get("events"), list):
                break
            try:
                fresh = [parse_event(e) for e in reply["events"]]
            except ValueError as exc:
                self._count("invalid", f"rollouts: {exc}")
                break
            with self._events_lock:
                last = self._events[-1].at if self._events else None
                self._events.extend(e for e in fresh if last is None or e.at > last)
            if reply.get("more") is not True or not fresh:
                break
        with self._events_lock:
            return list(self._events)

    def take_events(self, events: Sequence[RolloutEvent]) -> list[RolloutEvent]:
        """Add events known otherwise (the sidecar's final record) after the ones seen; all events, oldest first."""
        with self._events_lock:
            last = self._events[-1].at if self._events else None
            self._events.extend(e for e in events if last is None or e.at > last)
            return list(self._events)

    # -- the socket ----------------------------------------------------------------------------

    def close(self) -> None:
        with self._lock:
            self._drop()

    def _call(self, request: dict[str, Any]) -> dict[str, Any] | None:
        with self._lock:
            sock = self._connect()
            if sock is None:
                return None
            try:
                reply = exchange(sock, request, time.monotonic() + self._timeout_s, MAX_REPLY_BYTES)
            except (OSError, ValueError, RecursionError) as exc:  # RecursionError: JSON nested too deep
                self._drop()
                self._retry_at = time.monotonic() + self._retry_s
                self._count("failed", f"{type(exc).__name__}: {exc}")
                return None
        if not isinstance(reply, dict) or reply.get("ok") is not True:
            error = reply.get("error") if isinstance(reply, dict) else None
            if request["op"] == "monitor" and isinstance(reply, dict) and reply.get("error_type") == "UnknownOp":
                self._monitor_unknown = True  # a sidecar of an image before the op: never asked again
                return None
            self._count("failed", f"the connector refused {request['op']}: {str(error)[:200]}")
            return None
        self._metrics.observer_requests.labels(result="ok").inc()
        return reply

    def _connect(self) -> socket.socket | None:
        if self._sock is not None:
            return self._sock
        if time.monotonic() < self._retry_at:
            return None
        path = self._path()
        if path is None:
            return None
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self._timeout_s)
        try:
            connect_long(sock, path)
        except OSError as exc:
            sock.close()
            self._retry_at = time.monotonic() + self._retry_s
            self._count("unreachable", f"{path}: {exc} (with the agent in a pod: is the kubelet's pods directory "
                                       "mounted with HostToContainer propagation, and --kubelet-root-dir right?)")
            return None
        self._sock = sock
        return sock

    def _drop(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def _count(self, result: str, problem: str) -> None:
        self._metrics.observer_requests.labels(result=result).inc()
        self._problems.warning("the sidecar connector's observer socket: %s", problem)
