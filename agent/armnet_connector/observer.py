"""The connector's read-only observer socket: what the node agent may know of a job it cannot call into.

With the pod launcher the connector runs in the job's pod (a sidecar) and the
agent outside it, yet the agent publishes the cell's telemetry and records the
job's rollout history from what the connector knows, exactly as it does for a
connector in its own process. ``observer.sock`` carries that knowledge out:

- ``servos``: the positions the job's own reads left in the connector
  (``telemetry.job_servos``: no traffic on the job's bus);
- ``frames``: the latest frame of each camera the job opened
  (``telemetry.latest_frames``), subsampled to at most ``MAX_SENT_WIDTH`` pixels
  wide (the agent scales and encodes them as for an in-process connector);
- ``rollouts``: the rollout begins, ends and monitor verdicts recorded after a given time;
- ``monitor``: the completion monitor's verdict now (``telemetry.monitor_now``), for the page.

Why a socket of its own, in a directory of its own: the customer container
shares the pod's network namespace and the sockets volume, so anything served
there could be read or imitated by the tenant. The observer socket lives in a
volume mounted into the connector container only; the agent reaches it on the
host through the kubelet's directory of the pod's volumes. It is read-only by
construction (no op changes anything). The socket file is ``0666`` like the
others: the connector runs as a non-root user and the agent as root without
capabilities (no ``CAP_DAC_OVERRIDE``), so a stricter mode would lock the agent
out; the isolation is the volume (in the pod: the sidecar's only; on the host:
under the kubelet's root-only ``pods`` directory).
"""

from __future__ import annotations

import base64
from collections.abc import Mapping
from typing import Any

from .cell import CellState
from .errors import RequestError, failure_reply, protocol_error
from .session import Reply, Session
from .telemetry import CameraFrame, job_servos, latest_frames, monitor_now
from .telemetry_decode import ServoSample

OBSERVER_SOCKET = "observer.sock"
#: Frames wider than this are subsampled (every n-th pixel) before they cross the socket: the agent
#: publishes 320 px wide, so twice that keeps its scaling's quality and bounds a 4K camera's bytes.
MAX_SENT_WIDTH = 640
#: Rollout events per reply at most (the connector keeps 1024; the agent asks again for the rest).
MAX_EVENTS_PER_REPLY = 256


def servos_data(readings: Mapping[str, Mapping[str, ServoSample | None] | str] | None) -> Any:
    """``job_servos`` as JSON data: arm -> motor -> [position, load, temperature] or null, or why not."""
    if readings is None:
        return None
    data: dict[str, Any] = {}
    for arm, motors in readings.items():
        if isinstance(motors, str):
            data[arm] = motors
            continue
        data[arm] = {motor: None if s is None else [s.position, s.load, s.temperature] for motor, s in motors.items()}
    return data


def frame_data(frame: CameraFrame) -> dict[str, Any]:
    """One frame as JSON data: shape, colour order and the pixels (base64), subsampled to ``MAX_SENT_WIDTH``."""
    import numpy as np

    image = np.asarray(frame.image)
    step = max(1, -(-int(image.shape[1]) // MAX_SENT_WIDTH)) if image.ndim >= 2 else 1
    if step > 1:
        image = image[::step, ::step]
    image = np.ascontiguousarray(image)
    return {"shape": list(image.shape), "dtype": str(image.dtype), "bgr": frame.bgr,
            "data": base64.b64encode(image.tobytes()).decode("ascii")}


class ObserverSession(Session):
    """One agent connection on ``observer.sock``: four read ops, nothing else."""

    socket_name = "observer"

    def __init__(self, cell: CellState) -> None:
        super().__init__(cell)
        self.ops.update(servos=self.op_servos, frames=self.op_frames, rollouts=self.op_rollouts,
                        monitor=self.op_monitor)

    def handle(self, request: dict[str, Any]) -> Reply:
        """As every session, but not counted among the job's requests and errors (the agent's polls are not the job's)."""
        try:
            op = request.get("op")
            handler = self.ops.get(op) if isinstance(op, str) else None
            if handler is None:
                raise RequestError("UnknownOp", f"{OBSERVER_SOCKET} serves only the ops {sorted(self.ops)}")
            return handler(request)
        except Exception as exc:  # noqa: BLE001 - every failure becomes a reply
            return failure_reply(exc)

    def op_servos(self, request: dict[str, Any]) -> Reply:
        return {"ok": True, "servos": servos_data(job_servos(self.cell))}

    def op_frames(self, request: dict[str, Any]) -> Reply:
        if self.cell.stopping.is_set():
            return {"ok": True, "frames": {}}
        return {"ok": True, "frames": {name: frame_data(f) for name, f in latest_frames(self.cell).items()}}

    def op_monitor(self, request: dict[str, Any]) -> Reply:
        verdict = monitor_now(self.cell)
        return {"ok": True, "monitor": None if verdict is None else {
            "complete": verdict.complete, "score": verdict.score, "frame_at": verdict.frame_at}}

    def op_rollouts(self, request: dict[str, Any]) -> Reply:
        """The events recorded after ``after`` (a connector time; absent: all it keeps), oldest first."""
        after = request.get("after")
        if after is not None and (isinstance(after, bool) or not isinstance(after, int | float)):
            raise protocol_error("request field 'after' must be a number (a connector event time)")
        events = [e for e in list(self.cell.rollouts) if after is None or e.at > after]
        more = len(events) > MAX_EVENTS_PER_REPLY
        return {"ok": True, "more": more, "events": [
            {"kind": e.kind, "at": e.at, "index": e.index, "total": e.total, "outcome_controls": e.outcome_controls,
             "success": e.success, "score": e.score, "frame_at": e.frame_at}
            for e in events[:MAX_EVENTS_PER_REPLY]
        ]}
