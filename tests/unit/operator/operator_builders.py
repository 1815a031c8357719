"""Fluent builders and a frozen clock for the operator's pure core.

Tests read as specifications: ``a_job().with_embodiment("so-101").queued()``.
Every builder returns a new frozen model, so a base can be shared safely.
"""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime, timedelta

from armnet_operator.model import Cell, CellPhase, Job, JobPhase, Timing
from armnet_operator.quota import CellQuota, QuotaPeriod, Usage

NOW = datetime(2026, 1, 1, 12, 0, 0, tzinfo=UTC)
SO101 = "lerobot/so-101"
BIMANUAL = "lerobot/bimanual_so101"
TIMING = Timing(
    heartbeat_timeout=timedelta(seconds=30),
    claim_grace=timedelta(seconds=10),
    lost_grace=timedelta(seconds=60),
    cancel_force_after=timedelta(seconds=60),
    default_ttl=timedelta(hours=1),
)


def ago(seconds: float) -> datetime:
    return NOW - timedelta(seconds=seconds)


class JobBuilder:
    _counter = 0

    def __init__(self) -> None:
        JobBuilder._counter += 1
        self.job = Job(
            namespace="tenant-a",
            name=f"job-{JobBuilder._counter:05d}",
            created=ago(100),
            embodiment=SO101,
            uid=f"uid-{JobBuilder._counter}",
            resource_version="1",
        )

    def _with(self, **changes: object) -> JobBuilder:
        self.job = replace(self.job, **changes)  # type: ignore[arg-type]
        return self

    def named(self, name: str, namespace: str = "tenant-a") -> JobBuilder:
        return self._with(name=name, namespace=namespace)

    def with_embodiment(self, embodiment: str) -> JobBuilder:
        return self._with(embodiment=embodiment)

    def with_task(self, task: str) -> JobBuilder:
        return self._with(task=task)

    def with_priority(self, priority: int) -> JobBuilder:
        return self._with(priority=priority)

    def with_timeout(self, seconds: int) -> JobBuilder:
        return self._with(timeout_seconds=seconds)

    def started_ago(self, seconds: float) -> JobBuilder:
        return self._with(started_at=ago(seconds))

    def submitted_ago(self, seconds: float) -> JobBuilder:
        return self._with(created=ago(seconds))

    def created_at(self, moment: datetime) -> JobBuilder:
        return self._with(created=moment)

    def arrived_ago(self, seconds: float) -> JobBuilder:
        """Queued first by the operator ``seconds`` ago (``status.arrivedAt``)."""
        return self._with(arrived_at=ago(seconds))

    def with_ttl(self, seconds: int) -> JobBuilder:
        return self._with(ttl_seconds_after_finished=seconds)

    def without_finalizer(self) -> JobBuilder:
        return self._with(finalizers=())

    def cancelled_by_user(self) -> JobBuilder:
        return self._with(cancel=True)

    def being_deleted(self) -> JobBuilder:
        return self._with(deleting=True)

    def cancel_requested(self, seconds_ago: float) -> JobBuilder:
        return self._with(cancel=True, cancel_requested_at=ago(seconds_ago))

    def with_preflight(self, seconds: int = 30) -> JobBuilder:
        return self._with(preflight_seconds=seconds)

    def preflight_of(self, owner: Job) -> JobBuilder:
        """The pre-flight run of ``owner`` (``armnet.io/preflight-for`` its uid)."""
        return self._with(preflight_for=owner.uid, namespace=owner.namespace, name=f"{owner.name}-preflight")

    def new(self) -> Job:
        return self.job

    def queued(self) -> Job:
        return self._with(phase=JobPhase.QUEUED).job

    def dispatched_to(self, cell: str, seconds_ago: float = 60) -> Job:
        return self._with(phase=JobPhase.DISPATCHED, cell_name=cell, bound_at=ago(seconds_ago)).job

    def running_on(self, cell: str) -> Job:
        return self._with(phase=JobPhase.RUNNING, cell_name=cell, bound_at=ago(60)).job

    def finished(self, phase: JobPhase = JobPhase.SUCCEEDED, seconds_ago: float = 10, cell: str | None = None) -> Job:
        return self._with(phase=phase, finished_at=ago(seconds_ago), cell_name=cell).job


class CellBuilder:
    _counter = 0

    def __init__(self) -> None:
        CellBuilder._counter += 1
        self.cell = Cell(
            name=f"cell-{CellBuilder._counter:04d}",
            embodiment=SO101,
            resource_version="1",
            last_heartbeat=ago(1),
            phase=CellPhase.READY,
        )

    def _with(self, **changes: object) -> CellBuilder:
        self.cell = replace(self.cell, **changes)  # type: ignore[arg-type]
        return self

    def named(self, name: str) -> CellBuilder:
        return self._with(name=name)

    def with_embodiment(self, embodiment: str) -> CellBuilder:
        return self._with(embodiment=embodiment)

    def with_task(self, task: str) -> CellBuilder:
        return self._with(task=task)

    def with_grace(self, seconds: int) -> CellBuilder:
        return self._with(grace_period=timedelta(seconds=seconds))

    def as_preflight_twin(self) -> CellBuilder:
        """A simulated twin that runs pre-flights only (``spec.preflight: true``)."""
        return self._with(preflight=True)

    def cordoned(self) -> CellBuilder:
        return self._with(unschedulable=True)

    def silent_for(self, seconds: float) -> CellBuilder:
        return self._with(last_heartbeat=ago(seconds))

    def never_heard_from(self) -> CellBuilder:
        return self._with(last_heartbeat=None)

    def failing(self, *conditions: str) -> CellBuilder:
        return self._with(failing_conditions=tuple(conditions))

    def in_phase(self, phase: CellPhase) -> CellBuilder:
        return self._with(phase=phase)

    def claimed_by(self, job: Job | str, seconds_ago: float = 60) -> CellBuilder:
        key = job if isinstance(job, str) else job.key
        return self._with(current_job=key, claimed_at=ago(seconds_ago), phase=CellPhase.BUSY)

    def build(self) -> Cell:
        return self.cell

    def ready(self) -> Cell:
        return self.cell


def a_job() -> JobBuilder:
    return JobBuilder()


def a_cell() -> CellBuilder:
    return CellBuilder()


class QuotaBuilder:
    """``a_quota("team-a").nominal(2).in_cohort("lab")``: one tenant's share of SO-101 cells."""

    def __init__(self, namespace: str) -> None:
        self.quota = CellQuota(name=f"{namespace}-so101", namespace=namespace, embodiment=SO101, nominal_cells=1)

    def _with(self, **changes: object) -> QuotaBuilder:
        self.quota = replace(self.quota, **changes)  # type: ignore[arg-type]
        return self

    def named(self, name: str) -> QuotaBuilder:
        return self._with(name=name)

    def nominal(self, cells: int) -> QuotaBuilder:
        return self._with(nominal_cells=cells)

    def for_embodiment(self, embodiment: str) -> QuotaBuilder:
        return self._with(embodiment=embodiment)

    def for_task(self, task: str) -> QuotaBuilder:
        return self._with(task=task)

    def in_cohort(self, cohort: str, borrowing_limit: int | None = None) -> QuotaBuilder:
        return self._with(cohort=cohort, borrowing_limit=borrowing_limit)

    def weighing(self, weight: float) -> QuotaBuilder:
        return self._with(weight=weight)

    def with_credits(self, cell_hours: float, period: QuotaPeriod = QuotaPeriod.WEEK) -> QuotaBuilder:
        return self._with(credits_cell_hours=cell_hours, period=period)

    def preempting_lower_priorities(self) -> QuotaBuilder:
        """``spec.preemption.withinQuota: LowerPriority``."""
        return self._with(preempt_lower_priority=True)

    def build(self) -> CellQuota:
        return self.quota


def a_quota(namespace: str) -> QuotaBuilder:
    return QuotaBuilder(namespace)


def used(cell_seconds: float) -> Usage:
    """A quota's recorded usage, as last accrued just now."""
    return Usage(decayed_cell_seconds=cell_seconds, updated_at=NOW)
