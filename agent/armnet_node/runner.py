"""Runs one job on one cell, from launch (or adoption after a restart) to its terminal status.

The steps, each safe to repeat after a crash at any point:

1. resolve the job's Secrets (in its namespace only) and plan the launch; a
   missing Secret or an impossible plan ends ``failed`` before anything starts;
2. start the cell's connector for this job (in this process, on the cell's
   simulator) on the job's socket directory;
3. start the container or pod named after the job's UID (the engine or the API
   server refuses a second one: a job never runs twice), or adopt the one a
   previous agent started (``launchers``: container engine or pod);
4. write ``running`` + ``startedAt``; supervise (``armnet_launch.supervise``):
   output lines, progress, the deadline and grace window, graceful cancel;
5. write the terminal status, then remove the container. A container still
   present is the "not yet reported" fact: a restarted agent re-reads its log
   from the start and writes the same result.

A preemption (the operator's ``status.preemption``, ``preempt``) stops the run
at its next episode boundary through the same graceful path as a cancel, and
the run ends ``preempted`` (``node.preemption`` decides what it ends as).

Every terminal status the runner writes (step 1's failure included) is also
published on the job's status stream with its error, so a client following the
job says why it ended.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from pathlib import Path
from typing import Any

from armnet_connector.inputs import LocalOperatorInputs
from armnet_connector.interlock import TripReason
from armnet_core import JobResult, JobStatus
from armnet_core.api import TERMINAL_PHASES, JobPhase
from armnet_core.resources import PreemptionRequest
from armnet_core.times import status_time
from armnet_launch.pod_spec import SecretRef
from armnet_launch.supervise import JobHooks, SupervisorLimits, infra_failure, supervise
from armnet_launch.supervise.observe import EventKind, OutputEvent
from armnet_sim.presets import CellSimulator

from armnet_node import report
from armnet_node import rollout_history as rh
from armnet_node.completion_configmap import ConfigMapModels
from armnet_node.device_health import LOST_PREFIX, lost_job_error
from armnet_node.follower import guard_follower
from armnet_node.kube import AgentKube, Conflict, Gone, KubeError, SecretMissing
from armnet_node.launchers import JobLauncher, JobSession, SessionRequest
from armnet_node.metrics import AgentMetrics
from armnet_node.model import Cell, Job, cancel_reason, parse_job
from armnet_node.plan import HostPaths, LaunchError, completion_files_refused, plan_launch
from armnet_node.preemption import (
    STOPPED_AT_EPISODE_END,
    STOPPED_AT_EPISODE_WAIT,
    episode_wait_left,
    preempted_result,
    preemption_reason,
)
from armnet_node.publish import JobOutput, Link, inputs_bridge, job_output
from armnet_node.rollout_history import as_status
from armnet_node.rollout_recorder import RolloutRecorder
from armnet_node.uploads import TrackedJob, UploadQueue

log = logging.getLogger(__name__)

PROGRESS_FLUSH_S = 1.0
#: How often a preempted run's connector is asked whether the episode boundary came.
PREEMPT_POLL_S = 0.1
STATUS_RETRIES = 5
ADOPTED_TRIP = (
    "the node agent restarted while this job ran; its connector was re-created with the interlock "
    "tripped and refuses motion for the rest of the job"
)


@dataclass
class RunnerDeps:
    kube: AgentKube
    launcher: JobLauncher
    paths: HostPaths
    metrics: AgentMetrics
    link: Link
    #: Takes each job's output directory to the object store once the job ended (docs/outputs.md).
    uploads: UploadQueue
    #: Writes the classifier models Cells name by ConfigMap to files (None: a Cell naming one is refused).
    completion_models: ConfigMapModels | None = None


class JobRunner:
    """One job's thread. ``stop()`` asks for the graceful path (cancel, deletion, job gone)."""

    def __init__(
        self,
        job: Job,
        cell: Cell,
        sim: CellSimulator | None,
        deps: RunnerDeps,
        *,
        container: Any = None,
        on_done: Callable[[JobRunner], None] | None = None,
        device_problems: Callable[[], Sequence[str]] | None = None,
    ) -> None:
        """``device_problems``: what is wrong with the cell's devices now (the worker's device watch)."""
        self.job = job
        self.cell = cell
        self.sim = sim
        self.deps = deps
        self.adopted_container = container
        self.hooks = JobHooks()
        self.session: JobSession | None = None
        self._output: JobOutput = job_output(deps.link, job.namespace, job.uid)
        self._on_done = on_done
        self._progress: str | None = None
        self._rollout: dict[str, int] | None = None
        #: The job's rollout history (``status.rollouts``), kept across an agent restart.
        self.rollouts = RolloutRecorder(self._rollout_events, history=job.rollouts,
                                        on_overrule=deps.metrics.completion_overrules.inc)
        self._progress_dirty = threading.Event()
        self._finished = threading.Event()
        self._flush_stop = threading.Event()
        #: Held for each progress write; once the terminal write begins no progress write follows
        #: (a late one, without a resourceVersion, would put back an older rollout history).
        self._status_lock = threading.Lock()
        self._terminal_begun = False
        #: The terminal status is written: nothing left to stop.
        self.reported = False
        #: Why the agent itself stopped the job (a lost follower), written as the result's error.
        self._stop_reason: str | None = None
        #: The cell's device was lost while the job ran (``stop_device_lost``): the job ends failed with this.
        self._device_lost: str | None = None
        #: The job's result is its own from here (a cancel's or timeout's grace window opened, or it
        #: ended): a device lost later is not recorded. Guarded by ``_loss_lock`` with ``_device_lost``.
        self._loss_closed = False
        self._loss_lock = threading.Lock()
        #: A launch refused before anything starts (``start(refuse=...)``): the job's error.
        self._refused: str | None = None
        self._device_problems = device_problems or (lambda: ())
        #: The operator's preemption of this run (``preempt``), once asked; guarded by ``_stop_lock``
        #: with ``_cancelled`` and ``_preempt_stopped_at``.
        self._preemption: PreemptionRequest | None = None
        self._stop_lock = threading.Lock()
        #: A cancel was asked (``stop``): its result stands, the run is never counted as preempted.
        self._cancelled = False
        #: The agent began the graceful stop for the preemption: where (``preemption.STOPPED_AT_*``).
        self._preempt_stopped_at: str | None = None
        #: The session once its job started: a preemption asked earlier is applied then.
        self._started_session: JobSession | None = None
        #: The job's run is over (``supervise`` returned, or the runner ended): a preemption waits no more.
        self._job_ended = threading.Event()
        self._seen_at = time.monotonic()
        #: The job's latest scripted reset from its connector's record, once the job ended.
        self._final_auto_reset: Mapping[str, Any] | None = None
        self._thread = threading.Thread(target=self._run, name=f"armnet-job-{job.name}", daemon=True)
        self.hooks.on_deadline = self._deadline_reached

    @property
    def uid(self) -> str:
        return self.job.uid

    @property
    def done(self) -> bool:
        return self._finished.is_set()

    @property
    def device_lost(self) -> str | None:
        """The device loss this job ends ``failed`` for, or None (its own result stands)."""
        return self._device_lost

    def start(self, *, refuse: str | None = None) -> JobRunner:
        """Run the job; with ``refuse``, a launch still ours ends ``failed`` with that error before anything starts."""
        self._refused = refuse
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop like a timeout (interlock, grace window, kill), ending ``cancelled``.

        A cancel that begins before any device loss keeps its result: a loss after it is not recorded.
        A cancel also keeps it over a preemption, before or after the preemption's stop began: a
        cancelled job must not go back to the queue.
        """
        self._close_device_loss()
        with self._stop_lock:
            self._cancelled = True
        if not self.hooks.cancel_gracefully.is_set():
            log.info("stopping job %s (cancel, deletion or gone)", self.job.key)
        self.hooks.cancel_gracefully.set()

    def stop_follower_lost(self, message: str) -> None:
        """The job's following client went away (``node.follower``): cancel, saying why."""
        if self._stop_reason is None and not self.hooks.cancel_gracefully.is_set():
            self._stop_reason = message
            self.deps.metrics.follower_cancels.inc()
        self.stop()

    def stop_device_lost(self, message: str) -> None:
        """A device of the cell is lost (``node.device_watch``): stop like a timeout; the job ends failed.

        The same path as a cancel (the interlock trips naming ``message``, the grace window
        runs, then the kill), so a job that honours ``is_shutting_down`` can save its data.
        Not recorded once the job's own end is under way (a cancel's or a timeout's grace
        window opened, or the job ended): that job ends cancelled, timeout or as it exited.
        """
        with self._loss_lock:
            if self._loss_closed or self._device_lost is not None:
                return
            self._device_lost = message
        log.warning("job %s: stopping it: %s", self.job.key, message)
        self.hooks.cancel_gracefully.set()

    def preempt(self, request: PreemptionRequest) -> None:
        """Stop the run at its next episode boundary, for another job (the operator's ``status.preemption``).

        Once only: the worker calls it on every pass that sees the request. It never
        blocks the caller: a daemon thread asks the job's session (``on_preempt``, as
        soon as the job started), waits until the connector opened the grace window
        (the boundary came, or none was open), or ``episodeWaitSeconds`` from
        ``requestedAt`` passed, or the job ended; then begins the graceful stop as
        ``stop`` does, the interlock naming the preemption. The run ends ``preempted``.
        """
        with self._stop_lock:
            if self._preemption is not None or self._job_ended.is_set():
                return
            self._preemption = request
        log.info("job %s: preempted for %s (%s); it stops at its next episode boundary, within %d s",
                 self.job.key, request.for_job, request.message, request.episode_wait_seconds)
        threading.Thread(target=self._carry_out_preemption, args=(request,), name=f"armnet-preempt-{self.job.name}",
                         daemon=True).start()

    def _carry_out_preemption(self, request: PreemptionRequest) -> None:
        stopped_at = self._await_episode_boundary(request)
        if stopped_at is None:
            return  # the job ended first: its own result stands
        self._close_device_loss()
        with self._stop_lock:
            if self._cancelled or self.hooks.cancel_gracefully.is_set():
                return  # a cancel or a lost device began the stop first: theirs
            self._preempt_stopped_at = stopped_at
        log.info("job %s: stopping it for its preemption (%s)", self.job.key,
                 "the episode boundary came" if stopped_at == STOPPED_AT_EPISODE_END
                 else f"no episode boundary within {request.episode_wait_seconds} s")
        self.hooks.cancel_gracefully.set()

    def _await_episode_boundary(self, request: PreemptionRequest) -> str | None:
        """Where the stop comes (``STOPPED_AT_*``), once it is due; None when the job ended first."""
        give_up_at = time.monotonic() + episode_wait_left(request, datetime.now(UTC))
        why = preemption_reason(request)
        asked: JobSession | None = None
        while not self._job_ended.is_set():
            session = self._started_session
            if asked is None and session is not None:
                asked = session
                _quietly(partial(session.on_preempt, why), f"job {self.job.key}: asking for the preemption's stop")
            if asked is not None and _quietly(asked.preempt_began, f"job {self.job.key}: the boundary check"):
                return STOPPED_AT_EPISODE_END
            if time.monotonic() >= give_up_at:
                return STOPPED_AT_EPISODE_WAIT
            self._job_ended.wait(PREEMPT_POLL_S)
        return None

    def session_started(self, session: JobSession) -> None:
        """The job runs in ``session``: the graceful stop reaches its connector, and so does a preemption
        (one asked before now too)."""
        self.hooks.on_cancel = lambda: session.on_cancel(self._cancel_why())
        self._started_session = session

    @property
    def preemption(self) -> PreemptionRequest | None:
        """The preemption this run was asked (``preempt``), if any."""
        return self._preemption

    @property
    def preemption_stopped_at(self) -> str | None:
        """Where the agent began the stop for the preemption (``preemption.STOPPED_AT_*``), None: it did not."""
        return self._preempt_stopped_at

    def _cancel_why(self) -> str | None:
        """What the interlock names when the graceful stop opens: a lost device, the preemption, or
        (None) the connector's own words for a cancel."""
        if self._device_lost is not None:
            return self._device_lost
        with self._stop_lock:
            request = self._preemption if self._preempt_stopped_at is not None else None
        return preemption_reason(request) if request is not None else None

    def settle_device_loss(self) -> str | None:
        """The job ended (``supervise`` returned): no loss is recorded from now, and a preemption waits no
        more (the job's own end came first); the loss recorded before, if any."""
        self._job_ended.set()
        return self._close_device_loss()

    def _close_device_loss(self) -> str | None:
        with self._loss_lock:
            self._loss_closed = True
            return self._device_lost

    def _deadline_reached(self) -> None:
        """The job's timeout opened its grace window: it ends ``timeout``; then the connector trips."""
        self._close_device_loss()
        session = self.session
        if session is not None:
            session.on_deadline()

    def interlock_trip(self) -> str | None:
        session = self.session
        return session.interlock_trip() if session is not None else None

    def auto_reset_latest(self) -> Mapping[str, Any] | None:
        """The job's latest scripted reset (``AutoResetReport.as_status()``): live from an in-process connector,
        else from the connector's record once the job ended; None when it made none (or it is not known yet)."""
        session = self.session
        live = session.auto_reset_latest() if session is not None else None
        return live if live is not None else self._final_auto_reset

    # -- the run -------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._run_job()
        except Exception as exc:  # noqa: BLE001 - an agent bug fails the job, never the agent
            log.exception("job %s: the agent failed running it", self.job.key)
            self._publish_end(self._write_terminal(infra_failure(
                f"the node agent failed: {type(exc).__name__}: {exc}", SupervisorLimits(self.job.timeout_seconds)), None))
        finally:
            self._job_ended.set()
            self._finished.set()
            if self._on_done is not None:
                self._on_done(self)

    def _run_job(self) -> None:
        job, cell = self.job, self.cell
        adopted = self.adopted_container is not None
        if not adopted and not self._still_dispatched():
            return
        if not adopted and self._refused is not None:
            self._fail_before_start(self._refused)
            return
        files_refused = None if adopted else completion_files_refused(cell, self.deps.paths)
        if files_refused is not None:
            models = self.deps.completion_models
            why = models.problem(cell.name) if models is not None else None
            self._fail_before_start(f"{files_refused}: {why}" if why else files_refused)
            return
        launcher = self.deps.launcher
        try:
            if launcher.secrets_by_ref:
                refs = tuple(SecretRef(*key) for key in self.deps.kube.secret_keys(job.namespace, job.secrets))
                plan = plan_launch(job, cell, self.deps.paths, {})
            else:
                refs = ()
                plan = plan_launch(job, cell, self.deps.paths, self.deps.kube.resolve_secrets(job.namespace, job.secrets))
        except (SecretMissing, LaunchError) as exc:
            self._fail_before_start(str(exc))
            return
        # Tracked before the directory exists: an agent killed from here on still uploads it.
        self.deps.uploads.track(TrackedJob(job.namespace, job.name, job.uid))
        for directory in (plan.layout.cache_dir, plan.layout.volume_dir, plan.layout.output_dir,
                          plan.layout.record_dir):
            if directory is not None:
                directory.mkdir(parents=True, exist_ok=True)
        inputs = LocalOperatorInputs()
        output = self._output
        request = SessionRequest(
            job=job, cell=cell, plan=plan, sim=self.sim, adopted=self.adopted_container,
            tripped=ADOPTED_TRIP if adopted else None, inputs=inputs,
            on_grace_expired=self.hooks.kill_now.set, secret_refs=refs,
            stop_requested=self.hooks.cancel_gracefully.is_set,
        )
        bridge = None
        follower = None
        try:
            with launcher.session(request) as session:
                self.session = session
                bridge = inputs_bridge(self.deps.link, session.operator_inputs(), namespace=job.namespace, job_uid=job.uid,
                                       cell=cell.name, active_rollout=self._active_rollout,
                                       on_verdict=self._record_verdict,
                                       accepts_verdict=self.rollouts.accepts_verdict,
                                       on_overrule=self._record_overrule)
                try:
                    launched = session.start()
                except Exception as exc:  # noqa: BLE001 - engine errors end the job failed with a short error
                    self._fail_before_start(_engine_error(exc, job.image))
                    return
                self.session_started(session)
                self._count_start(adopted)
                started_at = self._mark_running(adopted)
                if started_at is None:
                    launched.kill()
                    session.remove()
                    return
                output.status(JobPhase.RUNNING, {"startedAt": status_time(started_at)})
                follower = guard_follower(self.deps.link, job.namespace, job.uid, job.follower_window_s,
                                          self.stop_follower_lost)
                # The job's clock runs from startedAt (also across an agent restart).
                elapsed = (datetime.now(UTC) - started_at).total_seconds()
                limits = SupervisorLimits(
                    timeout_seconds=plan.timeout_seconds, grace_seconds=plan.grace_seconds,
                    already_elapsed_s=max(elapsed, 0.0),
                )
                self.hooks.on_event = self._event_sink(output)
                flusher = threading.Thread(target=self._flush_progress, daemon=True)
                flusher.start()
                result = supervise(launched, limits, self.hooks)
                device_lost = self.settle_device_loss()  # a loss recorded after this does not change the result
                self.rollouts.sync()  # the last begins and ends, before the connector stops
                record = session.record()
                self.rollouts.sync()  # a pod's sidecar may stop before the sync above: its record has the last
                self._final_auto_reset = auto_resets(record).get("latest")
                keep_rollouts(plan.layout.record_dir, self.rollouts.history)
                result = self.final_result(result, session.failure(), device_lost, record, limits)
                self._flush_stop.set()  # the last progress write lands before the terminal one
                flusher.join(PROGRESS_FLUSH_S * 2)
                with self._status_lock:  # waits out a progress write still in flight
                    self._terminal_begun = True
                written = self._write_terminal(result, record)
                self.reported = True
                if written is not None:
                    self._publish_end(written)
                    self._count(result, record, started_at)
                session.remove()
        finally:
            self._flush_stop.set()
            if follower is not None:
                follower.close()
            if bridge is not None:
                bridge.close()
            self.session = None
            shutil.rmtree(plan.layout.socket_dir.parent, ignore_errors=True)
            if self.reported:
                # The output is final: to the object store (or removed without one).
                self.deps.uploads.ready(job.uid)
            else:
                # No terminal status from here (the agent stops, or the job failed before it
                # started): the agent that adopts the job takes it, or the queue's sweep once
                # the job is terminal or gone.
                self.deps.uploads.released(job.uid)

    def final_result(self, result: JobResult, failure: str | None, device_lost: str | None,
                     record: report.ConnectorRecord, limits: SupervisorLimits) -> JobResult:
        """The run's result from the supervisor's: an infrastructure failure (``failure``), then a lost device,
        then the preemption, each over the ones after it.

        An infrastructure failure does not replace a timeout or a cancel (their grace window
        explains the end); a lost device (``device_lost``, or one missing now while the job
        failed) replaces what ``device_health.lost_job_error`` says. A result either replaced,
        or a cancel's, is not the preemption's.
        """
        own = result
        if failure is not None and result.status not in (JobStatus.TIMEOUT, JobStatus.CANCELLED):
            result = infra_failure(failure, limits)
        elif result.status is JobStatus.CANCELLED and self._stop_reason is not None:
            result = result.model_copy(update={"error": self._stop_reason})
        lost = lost_job_error(result.status, device_lost, tuple(self._device_problems()))
        if lost is not None:
            return result.model_copy(update={"status": JobStatus.FAILED, "error": lost})
        if result is not own:
            return result
        return self._preempted(result, record)

    def _preempted(self, result: JobResult, record: report.ConnectorRecord) -> JobResult:
        """``preempted`` when the preemption opened the job's grace window before the job ended (and no
        cancel was asked): the agent's stop for it, or the connector's at the boundary, as its record says."""
        with self._stop_lock:
            request, cancelled, stopped_at = self._preemption, self._cancelled, self._preempt_stopped_at
        if request is None or cancelled:
            return result
        by_connector = record.trip_reason == TripReason.DEADLINE and record.trip_message == preemption_reason(request)
        by_agent = stopped_at is not None and result.status is JobStatus.CANCELLED
        return preempted_result(result, request, stopped=by_agent or by_connector)

    def _count_start(self, adopted: bool) -> None:
        if adopted:
            self.deps.metrics.jobs_adopted.inc()
        else:
            self.deps.metrics.jobs_started.inc()
            self.deps.metrics.launch_latency.observe(time.monotonic() - self._seen_at)

    def _still_dispatched(self) -> bool:
        """A fresh read right before launch: a stale list must never start a job twice."""
        try:
            current = parse_job(self.deps.kube.read_job(self.job.namespace, self.job.name))
        except Gone:
            return False
        return current.uid == self.job.uid and current.phase == JobPhase.DISPATCHED and not current.stopping

    def _mark_running(self, adopted: bool) -> datetime | None:
        """``running`` + ``startedAt`` (kept if already written); None if the job is no longer ours."""
        for _ in range(STATUS_RETRIES):
            try:
                current = parse_job(self.deps.kube.read_job(self.job.namespace, self.job.name))
            except Gone:
                return None
            if current.uid != self.job.uid or current.phase in TERMINAL_PHASES:
                return None
            if current.stopping:
                self.stop()
            if current.phase == JobPhase.RUNNING and current.started_at is not None:
                return current.started_at
            now = datetime.now(UTC)
            try:
                self.deps.kube.patch_job_status(
                    current.namespace, current.name, report.running_patch(current.resource_version, now)
                )
                return now
            except Conflict:
                continue
        raise KubeError(f"could not mark {self.job.key} running: it kept changing")

    def _event_sink(self, output: Any) -> Callable[[OutputEvent], None]:
        sequence = {"stdout": 0, "stderr": 0, "progress": 0, "rerun": 0}
        metrics = self.deps.metrics

        def sink(event: OutputEvent) -> None:
            kind = "rerun" if event.kind is EventKind.RERUN else (
                "progress" if event.kind is EventKind.PROGRESS else event.stream.value)
            sequence[kind] += 1
            output.line(kind, sequence[kind], event.text)
            metrics.lines_published.inc()
            if event.kind is EventKind.PROGRESS:
                self._progress = event.text
                self._progress_dirty.set()

        return sink

    def _flush_progress(self) -> None:
        """At most one progress/rollout write per second, latest value wins."""
        while not self._flush_stop.wait(PROGRESS_FLUSH_S):
            rollout = self._latest_rollout()
            if rollout is not None and rollout != self._rollout:
                self._rollout = rollout
                self._progress_dirty.set()
            force = self._progress_dirty.is_set()
            self._progress_dirty.clear()  # a progress line arriving during the write sets it again
            with self._status_lock:
                if self._terminal_begun:
                    return
                written = write_progress(self.deps.kube, self.job, self._progress, self._rollout,
                                         self.rollouts, force=force)
            if not written and force:
                self._progress_dirty.set()  # the write failed: try again on the next pass

    def _latest_rollout(self) -> dict[str, int] | None:
        session = self.session
        return session.rollout() if session is not None else None

    def _rollout_events(self) -> list[Any]:
        session = self.session
        try:
            return list(session.rollout_events()) if session is not None else []
        except RuntimeError:  # the connector's deque changed while copied: the next pass takes them
            return []

    def _record_verdict(self, success: bool, by: str, rollout: int | None) -> None:
        """A verdict the bridge passed to the job: into the history, written with the next progress write."""
        try:
            self.rollouts.verdict(success, by, rollout)
            self.deps.metrics.rollout_verdicts.labels(outcome="success" if success else "failure").inc()
        except Exception:  # noqa: BLE001 - the record must never stop the bridge delivering inputs
            log.exception("job %s: the verdict by %s was not recorded", self.job.key, by[:128])

    def _record_overrule(self, success: bool, by: str, rollout: int, started_at: datetime) -> bool:
        """An overrule of the monitor from the FMS: into the history, written with the next progress write."""
        try:
            return self.rollouts.overrule(success, by, rollout, started_at)
        except Exception:  # noqa: BLE001 - the record must never stop the bridge delivering inputs
            log.exception("job %s: the overrule by %s was not recorded", self.job.key, by[:128])
            return False

    def _active_rollout(self) -> int | None:
        """The index of the rollout the job is in now (operator verdicts for any other are dropped)."""
        session = self.session
        return session.active_rollout() if session is not None else None

    # -- status writes ----------------------------------------------------------------

    def _fail_before_start(self, error: str) -> None:
        log.warning("job %s failed before start: %s", self.job.key, error)
        now = datetime.now(UTC)
        self._publish_end(self._write(lambda current: report.failed_before_start(current.resource_version, error, now)))
        self.deps.metrics.jobs_finished.labels(outcome="failed").inc()

    def _publish_end(self, written: dict[str, Any] | None) -> None:
        """The terminal status just written, on the job's status stream (nothing when none was written)."""
        if written is not None:
            self._output.status(written["status"]["phase"],
                                report.end_detail(written, requeue_on_preemption=self.job.requeue_on_preemption))

    def _write_terminal(self, result: JobResult, record: report.ConnectorRecord | None) -> dict[str, Any] | None:
        def body(current: Job) -> dict[str, Any]:
            reason = cancel_reason(current) if result.status is JobStatus.CANCELLED else None
            final = result.model_copy(update={"error": reason}) if reason else result
            return report.terminal_patch(current.resource_version, final, record, as_status(self.rollouts.history))

        return self._write(body)

    def _write(self, body_for: Callable[[Job], dict[str, Any]]) -> dict[str, Any] | None:
        """A terminal write on the job as it is now; never over another terminal phase. The body written, or None."""
        announce_upload = True
        for _ in range(STATUS_RETRIES):
            try:
                current = parse_job(self.deps.kube.read_job(self.job.namespace, self.job.name))
            except Gone:
                return None
            if current.uid != self.job.uid or current.phase in TERMINAL_PHASES:
                return None
            body = body_for(current)
            pending = self.deps.uploads.pending_status(current.uid) if announce_upload else None
            if pending is not None:
                body["status"]["artifacts"] = pending
            try:
                self.deps.kube.patch_job_status(current.namespace, current.name, body)
                return body
            except Conflict:
                continue
            except Gone:
                return None
            except KubeError as exc:
                if pending is None:
                    raise
                # A CRD older than this agent (an upgrade in progress) refuses the Pending phase: the terminal
                # status matters, the announcement does not (a waiting client then returns without it).
                log.warning("job %s: terminal status with Pending artifacts refused (%s); written without",
                            self.job.key, exc)
                announce_upload = False
        log.error("job %s: terminal status not written after %d conflicts", self.job.key, STATUS_RETRIES)
        return None

    def _count(self, result: JobResult, record: report.ConnectorRecord, started_at: datetime) -> None:
        metrics = self.deps.metrics
        metrics.jobs_finished.labels(outcome=result.status.value).inc()
        if result.status is JobStatus.FAILED and (result.error or "").startswith(LOST_PREFIX):
            metrics.device_lost_jobs.inc()
        metrics.job_duration.observe(max((datetime.now(UTC) - started_at).total_seconds(), 0.0))
        if result.status is JobStatus.TIMEOUT:
            metrics.timeouts.inc()
        if result.status is JobStatus.PREEMPTED:
            metrics.preemptions.labels(stopped_at=self.preemption_stopped_at or STOPPED_AT_EPISODE_END).inc()
        if record.trip_reason is not None:
            metrics.interlock_trips.labels(reason=record.trip_reason).inc()
        count_auto_resets(metrics, record)
        count_cell_record(metrics, record)


#: ``armnet_agent_auto_resets_total``'s outcome label -> the key of the record's ``autoResets`` that counts it.
AUTO_RESET_OUTCOMES = (("worked", "worked"), ("try_failed", "failedAttempts"), ("fell_back", "fell_back"),
                       ("stopped", "stopped"))


def count_auto_resets(metrics: AgentMetrics, record: report.ConnectorRecord) -> None:
    """Add an ended job's scripted resets, by outcome (each failed try too), to ``armnet_agent_auto_resets_total``."""
    resets = auto_resets(record)
    for outcome, key in AUTO_RESET_OUTCOMES:
        count = resets.get(key)
        if isinstance(count, int) and count > 0:
            metrics.auto_resets.labels(outcome=outcome).inc(count)


def count_cell_record(metrics: AgentMetrics, record: report.ConnectorRecord) -> None:
    """Add what an ended job's cell record kept and dropped, per part, to ``armnet_agent_cell_record_items_total``."""
    for part, counts in record.cell_record.items():
        for outcome, count in counts.items():
            if count > 0:
                metrics.cell_record_items.labels(part=part, outcome=outcome).inc(count)


def auto_resets(record: report.ConnectorRecord) -> Mapping[str, Any]:
    """The scripted resets of the connector's record (its safety report's ``autoResets``), {} when none."""
    resets = record.safety.get("autoResets") if isinstance(record.safety, Mapping) else None
    return resets if isinstance(resets, Mapping) else {}


def keep_rollouts(record_dir: Path | None, history: rh.History) -> None:
    """The job's rollout history (``status.rollouts`` as written) in the cell's record, beside the rollouts'
    pictures, so the stored record says which verdict each picture got and which were overruled."""
    if record_dir is None or not history:
        return
    data = json.dumps({"rollouts": as_status(history)}, indent=1).encode()
    try:
        record_dir.mkdir(parents=True, exist_ok=True)
        # In a pod the directory is the connector's: nothing in it is followed (a planted link must not
        # make the agent write elsewhere). The parent is the agent's, so the directory itself is ours to trust.
        directory = os.open(record_dir, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
        try:
            partial = ".rollouts.json.partial"
            try:
                os.unlink(partial, dir_fd=directory)
            except FileNotFoundError:
                pass
            fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644, dir_fd=directory)
            with os.fdopen(fd, "wb") as file:
                file.write(data)
            os.replace(partial, "rollouts.json", src_dir_fd=directory, dst_dir_fd=directory)
        finally:
            os.close(directory)
    except OSError as exc:
        log.warning("the rollout history was not kept in the cell's record %s: %s", record_dir, exc)


def write_progress(kube: AgentKube, job: Job, progress: str | None, rollout: dict[str, int] | None,
                   rollouts: RolloutRecorder, *, force: bool) -> bool:
    """One progress write: the progress and rollout (when ``force``) and the rollout history if it changed.

    False when there was nothing to write or the write failed (the caller tries again on its next pass).
    """
    rollouts.sync()
    history = rollouts.unwritten()
    if not force and history is None:
        return False
    body = report.progress_patch(progress, rollout, as_status(history) if history is not None else None)
    try:
        kube.patch_job_status(job.namespace, job.name, body)
    except KubeError as exc:
        log.warning("job %s: progress not written: %s", job.key, exc)
        return False
    if history is not None:
        rollouts.written(history)
    return True


def _quietly(call: Callable[[], Any], what: str) -> Any:
    """``call()``, or None after logging what failed: a session's error must not end the preemption's wait
    (the wait's end still opens the grace window)."""
    try:
        return call()
    except Exception:  # noqa: BLE001 - logged; the caller goes on
        log.exception("%s failed", what)
        return None


def _engine_error(exc: Exception, image: str) -> str:
    from docker.errors import ImageNotFound, NotFound
    from kubernetes.client.exceptions import ApiException

    if isinstance(exc, ImageNotFound | NotFound):
        return f"image {image} not found on this node; push it to a registry the node can pull from"
    if isinstance(exc, ApiException):
        return f"the API server refused the job's pod: {exc.status} {exc.reason}: {str(exc.body)[:300]}"
    return f"the launcher failed to start the job: {type(exc).__name__}: {str(exc)[:300]}"
