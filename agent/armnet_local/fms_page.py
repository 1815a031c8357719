"""``armnet run --fms PORT``: the cell operator's page for the local simulated cell.

The same page as ``armnet fms`` (``armnet_fms.local``), fed by this run: the
reset waits of the job's connector become Confirm buttons, Success/Fail reach
``ctx.cell.is_complete()``, Stop cancels the run gracefully (interlock, grace
window) like a cluster job. So a customer can click through a reset and
outcome flow on their laptop. Served on 127.0.0.1 only, behind a token printed
for this run.

The cameras and servo plots come from the agent's own telemetry code: a
``CellTelemetry`` thread over a ``JobSource`` of the run's connector (the
positions of the job's reads, the frames of the cameras it opened, the
simulator's picture for the others), publishing the same ``telemetry.local.*``
messages an agent puts on NATS, straight into the page's store.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from armnet_connector.inputs import LocalOperatorInputs
from armnet_core.api import JobPhase
from armnet_launch.supervise import JobHooks
from armnet_launch.supervise.observe import EventKind, OutputEvent
from armnet_node.metrics import AgentMetrics
from armnet_node.telemetry import CellTelemetry, TelemetrySettings, TelemetrySource
from armnet_node.telemetry_sources import InProcessView, JobSource

if TYPE_CHECKING:
    from armnet_launch.sim_cell import LocalCell

LOCAL_CELL = "local"


class LocalPage:
    def __init__(self, port: int, job_id: str, reset_timeout_s: float, hooks: JobHooks,
                 telemetry: TelemetrySettings | None = None) -> None:
        from armnet_fms.local import LocalBus, LocalFleet, LocalServer
        from armnet_fms.telemetry import TelemetryStore

        self.inputs = LocalOperatorInputs()
        self.bus = LocalBus(LOCAL_CELL, job_id, self._deliver, telemetry=TelemetryStore())
        #: The agent's telemetry counters for this run (published / failed), as an agent exports them.
        self.metrics = AgentMetrics()
        self.telemetry = CellTelemetry(LOCAL_CELL, self._telemetry_source, self.bus, self.metrics,
                                       telemetry or TelemetrySettings())
        self.inputs.on_reset_requested = self.bus.announce_reset
        self.cell: LocalCell | None = None
        self.fleet = LocalFleet(LOCAL_CELL, job_id, reset_timeout_s=reset_timeout_s, rollout=self._rollout,
                                on_stop=hooks.cancel_gracefully.set)
        self.server = LocalServer(self.fleet, self.bus, port)

    def start(self) -> LocalPage:
        self.server.start()
        self.telemetry.start()
        return self

    def stop(self) -> None:
        self.telemetry.stop()
        self.telemetry.join(2.0)
        self.server.stop()

    def _telemetry_source(self) -> TelemetrySource | None:
        """The run's connector while the job runs (the same ``JobSource`` as a node agent's), else nothing."""
        cell = self.cell
        connector = cell.connector if cell is not None else None
        if cell is None or connector is None or self.fleet.phase != JobPhase.RUNNING:
            return None
        return JobSource(InProcessView(connector.cell), cell.spec.cameras, cell.sim)

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
