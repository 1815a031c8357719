"""``Connector``: the two sockets of one cell, started and stopped together.

This module owns the connector's lifetime (start the sockets and the deadline,
stop: release every device, remove the sockets) and the facts its host reads
at the end of a job. ``armnet run`` uses it in-process; ``armnet connector``
wraps it in a process.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from pathlib import Path
from types import MappingProxyType, TracebackType
from typing import TypeVar

from armnet_core.framing import BufferBudget
from armnet_runtime.endpoints import OPERATOR_SOCKET, ROBOT_SOCKET

from .agent_inputs import AGENT_SOCKET, AgentSession
from .camera_video import DRAIN_S as VIDEO_DRAIN_S
from .camera_video import CameraVideo
from .cell import CellState, Counters
from .completion import CameraCompletionMonitor, CameraFrames
from .config import ConnectorConfig
from .frames import FrameAreas
from .hardware import CameraFactory
from .inputs import CompletionMonitor, LocalOperatorInputs, NeverComplete, OperatorInputs
from .interlock import Interlock, TripReason
from .observer import OBSERVER_SOCKET, ObserverSession
from .record import ConnectorRecord
from .record_writer import RecordWriter, stop_writers
from .report import SafetyReport
from .rollout_frames import DRAIN_S, RolloutFrames
from .server import MAX_BUFFERED_BYTES, ServerLimits, UnixServer
from .servo_trace import DRAIN_S as TRACE_DRAIN_S
from .servo_trace import JOB_END, ServoTrace
from .session import OperatorSession, RobotSession, Session
from .warm_imports import start_warm_imports

log = logging.getLogger(__name__)

S = TypeVar("S", bound=Session)

OBSERVER_MAX_CONNECTIONS = 4
"""The agent keeps one connection; a restarted agent may open another before the old one closes."""
STOP_THREADS_WAIT_S = 1.0
"""How long ``stop`` waits for connection threads before releasing the devices: a call
in flight may finish; a hung one does not hold back torque off."""
STOP_LOCK_WAIT_S = 1.0
"""How long ``stop`` waits for each device a call still holds; then torque goes off beside it."""
TORQUE_OFF_RESERVE_S = 1.5
"""What ``stop`` keeps of its budget, per arm, for torque off after the rest walk: a
device-lock wait and a few writes and read-backs, with room for a loaded host."""


#: The parts of the cell's record of a job -> their counters (kept, dropped).
CELL_RECORD_PARTS = {
    "trace_rows": ("trace_rows_written", "trace_rows_dropped"),
    "video_frames": ("video_frames_written", "video_frames_dropped"),
    "rollout_pictures": ("rollout_frames_kept", "rollout_frames_dropped"),
}


def stop_budget_s(grace_period_seconds: float) -> float:
    """How long a clean stop may take before the process exits anyway: within the grace
    window the host gives the connector (never less than a few seconds to release torque)."""
    return max(5.0, grace_period_seconds - 1.0)


class Connector:
    """Serve one cell's ``robot.sock`` and ``operator.sock`` in ``socket_dir``.

    ``on_grace_expired`` is called when the grace window after the deadline
    closes: the host kills the job process then. ``camera_factory`` overrides
    how camera requests are served (a simulated cell passes one that draws its
    arms).
    """

    def __init__(
        self,
        config: ConnectorConfig,
        socket_dir: str | Path,
        *,
        inputs: OperatorInputs | None = None,
        completion: CompletionMonitor | None = None,
        camera_factory: CameraFactory | None = None,
        on_grace_expired: Callable[[], None] | None = None,
        observer_dir: str | Path | None = None,
        record_dir: str | Path | None = None,
    ) -> None:
        """``observer_dir``: where to serve the read-only ``observer.sock`` (observer.py) and the agent's
        ``agent.sock`` (agent_inputs.py: operator inputs and the cancel of a pod job), None: nowhere.

        ``record_dir``: the cell's record of the job, a directory the job cannot see (the node agent
        uploads it with the job's output): the servo trace (``servo_trace``), a video of each camera
        the job used (``camera_video``) and the rollouts' pictures (``rollout_frames``) go there."""
        self.config = config
        self.socket_dir = Path(socket_dir)
        self.cell = CellState(
            config,
            inputs if inputs is not None else LocalOperatorInputs(),
            completion=completion if completion is not None else NeverComplete(),
            camera_factory=camera_factory,
            on_grace_expired=on_grace_expired,
        )
        # The cell's own completion monitor when its config has one (and the host passed none).
        self.monitor: CameraCompletionMonitor | None = None
        if completion is None and config.completion is not None and self.cell.camera_factory is not None:
            name = config.completion.camera
            source = CameraFrames(self.cell.camera_factory, name, config.cameras[name])
            self.monitor = CameraCompletionMonitor(config.completion, source, self.cell.counters)
            self.cell.completion = self.monitor
            if record_dir is not None:
                self.cell.rollout_frames = RolloutFrames(Path(record_dir), self.monitor.latest_frame,
                                                         self.cell.counters)
                self.monitor.on_scored = self.cell.rollout_frames.scored
        if record_dir is not None:
            self._keep_record(Path(record_dir))
        # Camera frames reach the job through areas in the socket directory (frames.py).
        self.frames = FrameAreas(self.socket_dir)
        # Both sockets share one cap on unfinished request bytes (server.py).
        limits = ServerLimits(max_connections=config.max_connections)
        budget = self.request_budget = BufferBudget(MAX_BUFFERED_BYTES)
        self._servers = [
            UnixServer(
                self.socket_dir / ROBOT_SOCKET, self._job_starts(lambda: RobotSession(self.cell, self.frames)),
                self.cell.counters,
                limits=limits, budget=budget,
            ),
            UnixServer(
                self.socket_dir / OPERATOR_SOCKET, self._job_starts(lambda: OperatorSession(self.cell)),
                self.cell.counters,
                limits=limits, budget=budget,
            ),
        ]
        if observer_dir is not None:
            # The agent's read-only view from outside the pod: its own small cap, never the job's.
            self._servers.append(UnixServer(
                Path(observer_dir) / OBSERVER_SOCKET, lambda: ObserverSession(self.cell), self.cell.counters,
                limits=ServerLimits(max_connections=OBSERVER_MAX_CONNECTIONS),
            ))
            # The agent's inputs (a separate socket: the observer stays read-only), in the same agent-only volume.
            self._servers.append(UnixServer(
                Path(observer_dir) / AGENT_SOCKET, lambda: AgentSession(self.cell), self.cell.counters,
                limits=ServerLimits(max_connections=OBSERVER_MAX_CONNECTIONS),
            ))
        self._started = False

    def _keep_record(self, directory: Path) -> None:
        """The cell's flight recorder of the job: its servo trace and its cameras' video."""
        cell = self.cell
        trace = cell.servo_trace = ServoTrace(directory, cell.counters)
        cell.guard.recorder.trace = trace
        cell.interlock.on_trip = lambda trip: trace.event(
            JOB_END if trip.reason is TripReason.SHUTDOWN else "interlock_trip", detail=f"{trip.reason}: {trip.message}")
        cell.camera_video = CameraVideo(directory, cell.counters)

    def _record_writers(self) -> tuple[tuple[RecordWriter | None, float], ...]:
        """The cell's record of the job, each writer with the time its stop may take (None: not kept)."""
        cell = self.cell
        return ((cell.servo_trace, TRACE_DRAIN_S), (cell.camera_video, VIDEO_DRAIN_S), (cell.rollout_frames, DRAIN_S))

    def _job_starts(self, make: Callable[[], S]) -> Callable[[], S]:
        """A session factory for the job's sockets: the job's first connection starts its clock, if not yet
        (``clock_starts_with_job``: the job cannot move an arm before it connects)."""
        def session() -> S:
            self.cell.deadline.start()
            return make()
        return session

    # -- lifetime ------------------------------------------------------------------

    def start(self) -> Connector:
        start_warm_imports()  # LeRobot's device modules, off the first request's path (warm_imports.py)
        for server in self._servers:
            server.path.parent.mkdir(parents=True, exist_ok=True)  # the observer's may be elsewhere
        started: list[UnixServer] = []
        try:
            for server in self._servers:
                server.start()
                started.append(server)
        except BaseException:
            for server in started:
                server.stop()
            raise
        if not self.cell.config.clock_starts_with_job:
            self.cell.deadline.start()
        if self.monitor is not None:
            self.monitor.start()
        for writer, _drain_s in self._record_writers():
            if writer is not None:
                writer.start()
        self._started = True
        log.info("connector serving %s and %s in %s", ROBOT_SOCKET, OPERATOR_SOCKET, self.socket_dir)
        return self

    def stop(self) -> None:
        """Stop serving, release every device (torque off if configured), remove the sockets."""
        if not self._started:
            return
        self._started = False
        self.cell.stopping.set()
        self.cell.deadline.stop()
        self.cell.interlock.trip(TripReason.SHUTDOWN, "the connector is shutting down")
        if self.monitor is not None:
            self.monitor.stop()
        for server in self._servers:
            server.shut()
        log.info("connector stopping: connections cut")
        started = time.monotonic()
        for server in self._servers:
            server.join(started + STOP_THREADS_WAIT_S)
        reserve_s = TORQUE_OFF_RESERVE_S * max(1, len(self.config.arms))
        rest_deadline = started + stop_budget_s(self.config.grace_period_seconds) - reserve_s
        self.cell.shut_down(STOP_LOCK_WAIT_S, rest_deadline=rest_deadline)
        # After the arms are safe (the record waits, torque off does not), within what is left of the
        # stop's budget: a pod's record line is printed after this, before the kubelet's kill. The
        # record's writers finish side by side (record_writer).
        stop_writers(self._record_writers(), until=started + stop_budget_s(self.config.grace_period_seconds))
        log.info("connector stopped")

    def __enter__(self) -> Connector:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    # -- what the host reads ---------------------------------------------------------

    @property
    def robot_endpoint(self) -> str:
        return f"unix://{self.socket_dir / ROBOT_SOCKET}"

    @property
    def operator_endpoint(self) -> str:
        return f"unix://{self.socket_dir / OPERATOR_SOCKET}"

    @property
    def deadline_passed(self) -> bool:
        """The job ran past its timeout: its final status is ``timeout``."""
        return self.cell.deadline.deadline_passed

    @property
    def grace_expired(self) -> bool:
        return self.cell.deadline.grace_expired

    def pass_deadline(self, timeout_s: float | None = None) -> None:
        """Open the grace window now: the job ran out of its ``timeout_s`` (the host's clock; else the config's)."""
        self.cell.deadline.pass_deadline(timeout_s)

    def cancel(self, why: str | None = None) -> None:
        """Open the grace window now: the job was cancelled, or stopped for ``why`` (the interlock says so)."""
        if why is None:
            self.cell.deadline.cancel()
        else:
            self.cell.deadline.cancel(why)

    @property
    def interlock(self) -> Interlock:
        return self.cell.interlock

    @property
    def counters(self) -> Counters:
        return self.cell.counters

    def safety_report(self) -> SafetyReport:
        """The job's safety record so far (clamps, refusals, trips, torque off), as plain data.

        Torque off per arm: the cell's own bus at release (shutdown) has the last word;
        before that, the job's bus (its disconnect reads the torque back).
        """
        report = self.cell.guard.recorder.snapshot()
        confirmed = {**report.torque_off_confirmed, **self.cell.torque_confirmed}
        return dataclasses.replace(report, torque_off_confirmed=confirmed)

    def cell_record_counts(self) -> dict[str, dict[str, int]]:
        """What the cell's record of the job kept and dropped, per part (``CELL_RECORD_PARTS``): the agent's metric."""
        counters = self.cell.counters
        return {part: {"kept": getattr(counters, kept), "dropped": getattr(counters, dropped)}
                for part, (kept, dropped) in CELL_RECORD_PARTS.items()}

    def record(self) -> ConnectorRecord:
        """The job's account so far (interlock, safety, rest, torque off, counters, calibration, restores) as frozen data."""
        cell = self.cell
        trip = cell.interlock.trip_info
        report = cell.guard.recorder.snapshot()
        totals = {
            "safety_clamps": report.clamps_total,
            "safety_refusals": report.refusals_total,
            "safety_trips": report.interlock_trips,
        }
        return ConnectorRecord(
            interlock_tripped=trip is not None,
            trip_reason=str(trip.reason) if trip is not None else None,
            trip_message=trip.message if trip is not None else None,
            deadline_passed=cell.deadline.deadline_passed,
            safety_violations=cell.counters.safety_violations,
            rests=tuple(cell.rest_reports.values()),
            torque_off_confirmed=MappingProxyType(dict(cell.torque_confirmed)),
            counters=MappingProxyType({**dataclasses.asdict(cell.counters), **totals}),
            calibration_mismatches=MappingProxyType(dict(report.calibration_mismatches)),
            register_restore_failures=MappingProxyType(dict(report.restore_failures)),
        )
