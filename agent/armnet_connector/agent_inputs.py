"""The connector's agent-only input socket: operator inputs and the cancel notice for a pod job.

With the pod launcher the connector runs in the job's pod and the node agent
outside it, so the agent's NATS inputs bridge (``node.inputs_bridge``) cannot
hand the cell operator's clicks to the connector's ``OperatorInputs`` object in
its own process. ``agent.sock`` carries them in: reset confirmations, rollout
verdicts, teleop, stop, the cancel that opens the grace window
(``ctx.is_shutting_down``), the preemption that opens it at the job's next
episode boundary (``preempt``: at the end of the open rollout, at once between
rollouts; ``CellState.stop_at_episode_end``), and the notice that the job's
container started (``job_started``: a pod's connector starts the job's clock
then, or at the job's first connection, not at its own start, which precedes
the job's image pull).

Why a second socket next to ``observer.sock`` rather than write ops on it: the
observer stays read-only by construction (its session has no op that changes
anything), and the agent's clicks never queue behind a frames reply. Both live
in the volume mounted into the connector container only (the tenant cannot
reach either; see ``connector.observer``).

The checks are those of the in-process path, applied here where the facts are:

- a confirmation names the reset wait it answers (``wait``: the number
  ``reset_pending`` gave when the agent announced the wait; ``LocalOperatorInputs``
  numbers its waits); one for an earlier wait, or with none waiting, is dropped;
- a verdict names the rollout it judges (``rollout``, or null: whichever is
  active); one for another rollout, or for a rollout begun without outcome
  controls, is dropped.

A dropped input is a reply ``{"ok": true, "applied": false, "why": ...}``: the
agent counts and logs it; it is not an error of the connection.
"""

from __future__ import annotations

import math
from typing import Any

from armnet_core.api import MAX_STOP_REASON

from .cell import CellState
from .errors import RequestError, failure_reply, protocol_error
from .inputs import LocalOperatorInputs
from .session import Reply, Session

AGENT_SOCKET = "agent.sock"
MAX_ACTION_MOTORS = 64
TELEOP_EVENTS = ("next_episode", "rerecord_episode", "stop_recording")
MAX_CANCEL_WHY = MAX_STOP_REASON
"""Characters of a cancel's or a preemption's reason: it lands in the interlock's message and the job's record."""


class AgentSession(Session):
    """One agent connection on ``agent.sock``: operator inputs and the cancel, each checked as in-process."""

    socket_name = "agent"

    def __init__(self, cell: CellState) -> None:
        super().__init__(cell)
        self.ops.update(
            reset_pending=self.op_reset_pending, confirm_reset=self.op_confirm_reset, outcome=self.op_outcome,
            teleop_action=self.op_teleop_action, teleop_event=self.op_teleop_event, stop=self.op_stop,
            cancel=self.op_cancel, preempt=self.op_preempt, job_started=self.op_job_started,
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

    def _numbered(self) -> LocalOperatorInputs:
        inputs = self.cell.inputs
        if not isinstance(inputs, LocalOperatorInputs):
            raise RequestError("Unsupported", "this connector's operator inputs do not number reset waits")
        return inputs

    def op_reset_pending(self, request: dict[str, Any]) -> Reply:
        """The number of the reset wait that waits for a confirmation now (null: none waits)."""
        wait = self._numbered().pending_reset_wait()
        return {"ok": True, "pending": wait is not None, "wait": wait}

    def op_confirm_reset(self, request: dict[str, Any]) -> Reply:
        wait = request.get("wait")
        if type(wait) is not int:
            raise protocol_error("request field 'wait' must be an integer (the reset wait confirmed)")
        inputs = self._numbered()
        if not inputs.confirm_reset_wait(wait):
            waiting = inputs.pending_reset_wait()
            return _dropped(f"it confirms reset wait {wait}; " + (
                f"reset wait {waiting} waits now" if waiting is not None else "no reset waits for a confirmation"))
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
        """The job was cancelled, or stopped for ``why`` (a lost device): trip the interlock naming it and
        open the grace window now (the job's ``is_shutting_down`` turns true)."""
        why = request.get("why")
        if why is not None and not (isinstance(why, str) and 0 < len(why) <= MAX_CANCEL_WHY):
            raise protocol_error(f"request field 'why' must be null or a string of 1 to {MAX_CANCEL_WHY} characters")
        if why is None:
            self.cell.deadline.cancel()
        else:
            self.cell.deadline.cancel(why)
        return {"ok": True, "applied": True}

    def op_preempt(self, request: dict[str, Any]) -> Reply:
        """The job was preempted for ``why``: open the grace window at its next episode boundary.

        ``now``: the window is open on return (the job was between rollouts, or the
        window was open already); false, it opens when the job ends its open rollout.
        The op changes nothing the second time, so the agent may ask again to learn
        whether the boundary came.
        """
        why = request.get("why")
        if not (isinstance(why, str) and 0 < len(why) <= MAX_CANCEL_WHY):
            raise protocol_error(f"request field 'why' must be a string of 1 to {MAX_CANCEL_WHY} characters "
                                 "(the preemption's reason)")
        return {"ok": True, "applied": True, "now": self.cell.stop_at_episode_end(why)}

    def op_job_started(self, request: dict[str, Any]) -> Reply:
        """The job's container runs (the agent saw it start): the job's clock starts, if its first
        connection has not started it already (``clock_starts_with_job``; a later notice changes nothing)."""
        already = self.cell.deadline.started
        self.cell.deadline.start()
        return {"ok": True, "applied": True, "already_running": already}


def _dropped(why: str) -> Reply:
    return {"ok": True, "applied": False, "why": why}
