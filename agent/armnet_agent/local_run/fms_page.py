"""``armnet run --fms PORT``: the cell operator's page for the local simulated cell.

The same page as ``armnet fms`` (``armnet_fms.local``), fed by this run: the
reset waits of the job's connector become Confirm buttons, Success/Fail reach
``ctx.cell.is_complete()``, Stop cancels the run gracefully (interlock, grace
window) like a cluster job. So a customer can click through a reset and
outcome flow on their laptop. Served on 127.0.0.1 only, behind a token printed
for this run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from armnet_agent.connector.inputs import LocalOperatorInputs
from armnet_agent.supervise import JobHooks
from armnet_agent.supervise.observe import EventKind, OutputEvent

if TYPE_CHECKING:
    from armnet_agent.launch.sim_cell import LocalCell

LOCAL_CELL = "local"


class LocalPage:
    def __init__(self, port: int, job_id: str, reset_timeout_s: float, hooks: JobHooks) -> None:
        from armnet_fms.local import LocalBus, LocalFleet, LocalServer

        self.inputs = LocalOperatorInputs()
        self.bus = LocalBus(LOCAL_CELL, job_id, self._deliver)
        self.inputs.on_reset_requested = self.bus.announce_reset
        self.cell: LocalCell | None = None
        self.fleet = LocalFleet(LOCAL_CELL, job_id, reset_timeout_s=reset_timeout_s, rollout=self._rollout,
                                on_stop=hooks.cancel_gracefully.set)
        self.server = LocalServer(self.fleet, self.bus, port)

    def start(self) -> LocalPage:
        self.server.start()
        return self

    def stop(self) -> None:
        self.server.stop()

    def observe(self, event: OutputEvent) -> None:
        if event.kind is EventKind.PROGRESS:
            self.fleet.progress = event.text[:300]

    def finished(self, phase: str) -> None:
        self.fleet.phase = phase

    def _deliver(self, kind: str, message: dict[str, Any]) -> None:
        if kind == "reset.confirm":
            self.inputs.confirm_reset()
        elif kind == "outcome":
            rollout = message.get("rollout")
            if rollout is not None and rollout != self._active_rollout():
                return  # that rollout ended: the verdict must not end the next one
            self.inputs.report_outcome(bool(message.get("success")))

    def _active_rollout(self) -> int | None:
        connector = self.cell.connector if self.cell is not None else None
        events = list(connector.cell.rollouts) if connector is not None else []
        return events[-1].index if events and events[-1].kind == "begin" else None

    def _rollout(self) -> dict[str, int] | None:
        connector = self.cell.connector if self.cell is not None else None
        if connector is None:
            return None
        for event in reversed(list(connector.cell.rollouts)):
            if event.kind == "begin" and event.index is not None:
                return {"index": event.index, "total": event.total or 0}
        return None
