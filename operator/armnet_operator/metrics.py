"""Prometheus metrics of the operator, on their own registry so replicas in one process don't clash."""

from __future__ import annotations

from collections import Counter as Tally
from collections.abc import Iterable
from datetime import datetime
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, start_http_server

from .args import ArgsLimit
from .model import Cell, CellPhase, Job, JobPhase
from .pass_io import Outcome

_LATENCY_BUCKETS = (0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 300, 900, 3600)


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.jobs = Gauge("armnet_robotjobs", "RobotJobs by phase", ["phase"], registry=r)
        self.queue_depth = Gauge(
            "armnet_queue_depth", "Queued RobotJobs by embodiment and task", ["embodiment", "task"], registry=r
        )
        self.cells = Gauge("armnet_cells", "Cells by phase", ["phase"], registry=r)
        self.bind_latency = Histogram(
            "armnet_bind_latency_seconds", "Submit to bound (creation to dispatched)",
            buckets=_LATENCY_BUCKETS, registry=r,
        )
        self.queue_wait = Histogram(
            "armnet_queue_wait_seconds", "Time a job waited in the queue before it was bound",
            buckets=_LATENCY_BUCKETS, registry=r,
        )
        self.binds = Counter("armnet_binds_total", "Jobs bound to cells", registry=r)
        self.conflicts = Counter(
            "armnet_binding_conflicts_total", "Writes that lost a resourceVersion race", registry=r
        )
        self.requeues = Counter(
            "armnet_requeues_total", "Dispatched jobs put back in the queue (cell gone, offline or unclaimed)",
            registry=r,
        )
        self.preemptions = Counter(
            "armnet_preemptions_total",
            "Running jobs asked to stop at their next episode boundary, by why (reclaim: a borrowed cell "
            "goes back to the tenant that owns it; priority: a higher priority of the same tenant)", ["reason"], registry=r,
        )
        self.preemption_requeues = Counter(
            "armnet_preemption_requeues_total",
            "Preempted jobs whose copy (status.requeuedAs) was created to run them again", registry=r,
        )
        self.preflights = Counter(
            "armnet_preflights_total",
            "Pre-flights on a simulated twin given their verdict (passed: the job joined the queue for a real "
            "cell; failed: the job failed with PreflightFailed)", ["verdict"], registry=r,
        )
        self.outputs_removed = Counter(
            "armnet_job_outputs_removed_total",
            "Finished jobs whose stored outputs were removed with the job at its TTL (removed), or whose removal "
            "the object store refused or did not answer (failed: the job stays and the next pass tries again)",
            ["outcome"], registry=r,
        )
        for result in ("removed", "failed"):
            self.outputs_removed.labels(result)
        for verdict in ("passed", "failed"):
            self.preflights.labels(verdict)
        for reason in ("reclaim", "priority"):
            self.preemptions.labels(reason)
        self.errors = Counter("armnet_reconcile_errors_total", "Failed writes and reconcile passes", registry=r)
        self.object_errors = Counter(
            "armnet_reconcile_object_errors_total",
            "Objects a pass could not handle and skipped (each pass counts each such object)", ["kind"], registry=r,
        )
        self.failing = Gauge("armnet_objects_failing", "Objects the last pass skipped", ["kind"], registry=r)
        self.quotas_ignored = Gauge(
            "armnet_cellquotas_ignored", "CellQuotas the last pass did not apply (malformed, or a duplicate scope)",
            registry=r)
        self.leader = Gauge("armnet_operator_leader", "1 while this replica holds the Lease", registry=r)
        self.pass_seconds = Histogram("armnet_reconcile_seconds", "Duration of one reconcile pass", registry=r)
        self.admission_requests = Counter(
            "armnet_admission_requests_total",
            "RobotJob admission reviews the webhook answered, by outcome (allowed, denied, malformed)",
            ["outcome"], registry=r,
        )
        self.admission_rejections = Counter(
            "armnet_admission_rejections_total",
            "RobotJobs the webhook refused, by the spec.args limit they broke (depth, size, type)",
            ["limit"], registry=r,
        )
        for outcome in ("allowed", "denied", "malformed"):
            self.admission_requests.labels(outcome)
        for limit in ArgsLimit:
            self.admission_rejections.labels(limit.value)
        self._server: Any = None
        self._queue_labels: set[tuple[str, str]] = set()

    def serve(self, port: int, address: str) -> None:
        if port:
            self._server, _ = start_http_server(port, address, registry=self.registry)

    def close(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def observe(self, outcome: Outcome, jobs: Iterable[Job], cells: Iterable[Cell], now: datetime) -> None:
        jobs = list(jobs)
        for job, _cell in outcome.bound:
            self.bind_latency.observe(max(0.0, (now - job.created).total_seconds()))
            self.queue_wait.observe(max(0.0, (now - (job.queued_at or job.created)).total_seconds()))
        self.binds.inc(len(outcome.bound))
        self.conflicts.inc(outcome.conflicts)
        self.requeues.inc(outcome.requeued)
        for reason, count in outcome.preempted.items():
            self.preemptions.labels(reason).inc(count)
        self.preemption_requeues.inc(outcome.requeued_copies)
        for verdict, count in outcome.preflights.items():
            self.preflights.labels(verdict).inc(count)
        for result, count in outcome.outputs_removed.items():
            self.outputs_removed.labels(result).inc(count)
        self.errors.inc(outcome.errors)
        failing = Tally(failure.kind for failure in outcome.failed.values())
        for kind in ("RobotJob", "Cell"):
            self.object_errors.labels(kind).inc(failing.get(kind, 0))
            self.failing.labels(kind).set(failing.get(kind, 0))
        phases = Tally(str(j.phase or JobPhase.SUBMITTED) for j in jobs)
        for phase in JobPhase:
            self.jobs.labels(phase.value).set(phases.get(phase.value, 0))
        cell_phases = Tally(str(c.phase) for c in cells if c.phase)
        for cell_phase in CellPhase:
            self.cells.labels(cell_phase.value).set(cell_phases.get(cell_phase.value, 0))
        by_key = {j.key: j for j in jobs}
        depth = Tally((by_key[k].embodiment, by_key[k].task or "") for k in outcome.queue if k in by_key)
        for labels in self._queue_labels - set(depth):
            self.queue_depth.labels(*labels).set(0)
        for labels, count in depth.items():
            self.queue_depth.labels(*labels).set(count)
        self._queue_labels = set(depth)
        self.quotas_ignored.set(outcome.quotas_ignored)
