"""The connector's agent-only input socket: operator inputs and the cancel notice for a pod job.

With the pod launcher the connector runs in the job's pod and the node agent
outside it, so the agent's NATS inputs bridge (``node.inputs_bridge``) cannot
hand the cell operator's clicks to the connector's ``OperatorInputs`` object in
its own process. ``agent.sock`` carries them in: reset confirmations, rollout
verdicts, teleop, stop, and the cancel that opens the grace window
(``ctx.is_shutting_down``).

Why a second socket next to ``observer.sock`` rather than write ops on it: the
observer stays read-only by construction (its session has no op that changes
anything), and the agent's clicks never queue behind a frames reply. Both live
in the volume mounted into the connector container only (the tenant cannot
reach either; see ``connector.observer``).

The checks are those of the in-process path, applied here where the facts are:

- a confirmation names the reset wait it answers (``wait``: the number
  ``reset_pending`` gave when the agent announced the wait); one for an earlier
  wait, or with none waiting, is dropped (``LocalOperatorInputs`` drops one with
  none waiting too);
- a verdict names the rollout it judges (``rollout``, or null: whichever is
  active); one for another rollout, or for a rollout begun without outcome
  controls, is dropped.

A dropped input is a reply ``{"ok": true, "applied": false, "why": ...}``: the
agent counts and logs it; it is not an error of the connection.
"""

from __future__ import annotations

import math
import threading
from typing import Any

from .cell import CellState
from .errors import RequestError, failure_reply, protocol_error
from .inputs import LocalOperatorInputs
from .session import Reply, Session

AGENT_SOCKET = "agent.sock"
MAX_ACTION_MOTORS = 64
TELEOP_EVENTS = ("next_episode", "rerecord_episode", "stop_recording")


class ResetWaits:
    """Numbers each reset wait of one connector, so a confirmation can name the wait it answers.

    Installed as the sidecar inputs' ``on_reset_requested``: called each time a
    reset starts to wait (``LocalOperatorInputs.wait_reset_confirmation``).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._number = 0

    def __call__(self, inputs: LocalOperatorInputs) -> None:
        with self._lock:
            self._number += 1

    @property
    def number(self) -> int:
        with self._lock:
            return self._number


def install(inputs: Any) -> ResetWaits | None:
    """A ``ResetWaits`` hooked into ``inputs`` (a ``LocalOperatorInputs`` without a prompt), else None."""
    if not isinstance(inputs, LocalOperatorInputs) or inputs.on_reset_requested is not None:
        return None
    waits = ResetWaits()
    inputs.on_reset_requested = waits
    return waits


class AgentSession(Session):
    """One agent connection on ``agent.sock``: operator inputs and the cancel, each checked as in-process."""

    socket_name = "agent"

    def __init__(self, cell: CellState, waits: ResetWaits) -> None:
        super().__init__(cell)
        self.waits = waits
        self.ops.update(
            reset_pending=self.op_reset_pending, confirm_reset=self.op_confirm_reset, outcome=self.op_outcome,
            teleop_action=self.op_teleop_action, teleop_event=self.op_teleop_event, stop=self.op_stop,
            cancel=self.op_cancel,
        )

    def handle(self, request: dict[str, Any]) -> Reply:
        """As every session, but not counted among the job's requests and errors (the agent's are not the job's)."""
        try:
            op = request.get("op")
            handler = self.ops.get(op) if isinstance(op, str) else None
            if handler is None:
                raise RequestError("UnknownOp", f"{AGENT_SOCKET} serves only the ops {sorted(self.ops)}")
            return handler(request)
        except Exception as exc:  # noqa: BLE001 - every failure becomes a reply
            return failure_reply(exc)

    def op_reset_pending(self, request: dict[str, Any]) -> Reply:
        """Whether a reset waits for a confirmation now, and the number of the last wait begun."""
        return {"ok": True, "pending": self.cell.inputs.wait_reset_pending(0), "wait": self.waits.number}

    def op_confirm_reset(self, request: dict[str, Any]) -> Reply:
        wait = request.get("wait")
        if type(wait) is not int:
            raise protocol_error("request field 'wait' must be an integer (the reset wait confirmed)")
        if wait != self.waits.number:
            return _dropped(f"it confirms reset wait {wait}, the last wait is {self.waits.number}")
        if not self.cell.inputs.confirm_reset():
            return _dropped("no reset is waiting for a confirmation")
        return {"ok": True, "applied": True}

    def op_outcome(self, request: dict[str, Any]) -> Reply:
        success, rollout = request.get("success"), request.get("rollout")
        if not isinstance(success, bool):
            raise protocol_error("request field 'success' must be a boolean")
        if rollout is not None and type(rollout) is not int:
            raise protocol_error("request field 'rollout' must be an integer or null")
        events = list(self.cell.rollouts)
        active = events[-1] if events and events[-1].kind == "begin" else None
        if rollout is not None and (active is None or active.index != rollout):
            return _dropped(f"it is for rollout {rollout}, the active rollout is "
                            f"{active.index if active is not None else None}")
        if active is not None and active.outcome_controls is False:
            return _dropped(f"rollout {active.index} began without outcome controls (the job decides its outcome)")
        self.cell.inputs.report_outcome(success)
        return {"ok": True, "applied": True}

    def op_teleop_action(self, request: dict[str, Any]) -> Reply:
        action = request.get("action")
        if action is not None and not (
                isinstance(action, dict) and len(action) <= MAX_ACTION_MOTORS
                and all(isinstance(k, str) and len(k) <= 128 for k in action)
                and all(type(v) in (int, float) and math.isfinite(v) for v in action.values())):
            raise protocol_error(f"request field 'action' must be null or at most {MAX_ACTION_MOTORS} "
                                 "motor names to finite numbers")
        self.cell.inputs.set_teleop_action(action)
        return {"ok": True, "applied": True}

    def op_teleop_event(self, request: dict[str, Any]) -> Reply:
        event = request.get("event")
        if event not in TELEOP_EVENTS:
            raise protocol_error(f"request field 'event' must be one of {list(TELEOP_EVENTS)}")
        self.cell.inputs.push_teleop_event(event)
        return {"ok": True, "applied": True}

    def op_stop(self, request: dict[str, Any]) -> Reply:
        self.cell.inputs.request_stop()
        return {"ok": True, "applied": True}

    def op_cancel(self, request: dict[str, Any]) -> Reply:
        """The job was cancelled: open the grace window now (the job's ``is_shutting_down`` turns true)."""
        self.cell.deadline.cancel()
        return {"ok": True, "applied": True}


def _dropped(why: str) -> Reply:
    return {"ok": True, "applied": False, "why": why}
