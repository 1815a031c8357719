"""Scheduling: which waiting RobotJob goes to which free Cell, and why the rest wait.

Pure: input is a snapshot of jobs and cells (and CellQuotas with their usage)
plus ``now``; output is a plan. Tenants take turns by the fair-share rule
(``fairshare``: within nominal share first, then lowest weighted usage); within
a tenant the order is priority (higher first), then submission time (FIFO),
then name, so the plan is deterministic. Without CellQuotas every job belongs
to one unmanaged tenant and the order is exactly priority then FIFO. A job that
matches no free cell never blocks the jobs behind it (no head-of-line
blocking): each job draws from its own pool, and a tenant out of quota never
blocks another tenant.

Pre-flights (``preflight``) draw from their own pool: the pre-flight cells
(``Cell.preflight``) of their embodiment, whatever their task; no ordinary job is
ever bound to a pre-flight cell. A job whose pre-flight has not passed waits with
``PreflightRunning``, behind every other job in ``queuePosition``, and is never bound.

Cost: one sort of the waiting jobs, then O(log tenants) per job, so the cost
per decision grows only with log(queue length).
"""

from __future__ import annotations

import heapq
from collections import defaultdict, deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta

from .estimate import cell_queues, likely_occupancy, queue_starts, seats, typical_runs
from .fairshare import Ledger, Reclaim, holds_cell, plan_reclaim, plan_within_quota
from .health import derive_cell_phase, is_available
from .model import Cell, CellPhase, CellQueue, Job, QueuedReason
from .quota import DEFAULT_SHARING, CellQuota, FairSharing, Usage


@dataclass(frozen=True)
class Binding:
    job: Job
    cell: Cell


@dataclass(frozen=True)
class QueueEntry:
    reason: QueuedReason
    position: int
    message: str
    latest_start: datetime | None = None
    """When the job starts at the latest (``estimate``); None when it waits on no busy cell."""
    likely_start: datetime | None = None
    """When it likely starts, from its cells' recent runs (``estimate``); None with ``latest_start``."""


@dataclass(frozen=True)
class SchedulePlan:
    bindings: tuple[Binding, ...]
    queued: Mapping[str, QueueEntry]
    cell_queues: Mapping[str, CellQueue] = field(default_factory=dict)
    """Each cell's queue summary after this pass's bindings (``estimate.cell_queues``)."""
    reclaims: tuple[Reclaim, ...] = ()
    """Running jobs to preempt at their next episode boundary: borrowers for owners waiting
    (``fairshare.plan_reclaim``), then lower priorities for higher ones of one tenant (``plan_within_quota``)."""


def order_key(job: Job) -> tuple[int, datetime, datetime, str, str]:
    return job.queue_order


def occupied_cells(jobs: Iterable[Job], cells: Iterable[Cell]) -> set[str]:
    """A cell is occupied if it holds a claim or an active job names it."""
    taken = {cell.name for cell in cells if cell.current_job}
    taken.update(job.cell_name for job in jobs if job.active and job.cell_name)
    return taken


class _Pools:
    """Free, available cells by (embodiment, task) and by embodiment, popped lazily; pre-flight
    cells apart, by embodiment only (a pre-flight runs on any twin of its embodiment)."""

    def __init__(self, free: list[Cell]) -> None:
        free.sort(key=lambda c: c.name)
        self.by_pair: dict[tuple[str, str | None], deque[Cell]] = defaultdict(deque)
        self.by_embodiment: dict[str, deque[Cell]] = defaultdict(deque)
        self.twins: dict[str, deque[Cell]] = defaultdict(deque)
        for cell in free:
            if cell.preflight:
                self.twins[cell.embodiment].append(cell)
                continue
            self.by_pair[(cell.embodiment, cell.task)].append(cell)
            self.by_embodiment[cell.embodiment].append(cell)
        self.taken: set[str] = set()

    def pop(self, job: Job) -> Cell | None:
        if job.is_preflight:
            pool = self.twins.get(job.embodiment)
        elif job.task is None:
            pool = self.by_embodiment.get(job.embodiment)
        else:
            pool = self.by_pair.get((job.embodiment, job.task))
        while pool:
            cell = pool.popleft()
            if cell.name not in self.taken:
                self.taken.add(cell.name)
                return cell
        return None


class _Census:
    """Counts of cells and available cells per embodiment and (embodiment, task)."""

    def __init__(self, phases: Mapping[str, tuple[Cell, CellPhase]]) -> None:
        self.total: dict[object, int] = defaultdict(int)
        self.available: dict[object, int] = defaultdict(int)
        for cell, phase in phases.values():
            keys: tuple[object, ...] = ((_TWIN, cell.embodiment),) if cell.preflight else (
                cell.embodiment, (cell.embodiment, cell.task))
            for key in keys:
                self.total[key] += 1
                if is_available(phase):
                    self.available[key] += 1

    def reason(self, job: Job) -> tuple[QueuedReason, str]:
        emb, task = job.embodiment, job.task
        if job.is_preflight:
            return self._twin_reason(emb)
        if not self.total.get(emb):
            return (
                QueuedReason.NO_CELL_FOR_EMBODIMENT,
                f"no Cell has embodiment {emb!r}; register one (kubectl apply -f cell.yaml) "
                "or fix spec.embodiment",
            )
        key: object = emb if task is None else (emb, task)
        if task is not None and not self.total.get(key):
            return (
                QueuedReason.NO_CELL_FOR_EMBODIMENT_AND_TASK,
                f"no Cell of embodiment {emb!r} is configured for task {task!r}; "
                "drop spec.task to run on any cell of the embodiment",
            )
        if not self.available.get(key):
            return (
                QueuedReason.ALL_CELLS_UNAVAILABLE,
                f"all {self.total[key]} matching Cell(s) are offline, faulted or cordoned",
            )
        return (
            QueuedReason.ALL_CELLS_BUSY,
            f"all {self.available[key]} available matching Cell(s) are busy",
        )

    def _twin_reason(self, emb: str) -> tuple[QueuedReason, str]:
        key = (_TWIN, emb)
        if not self.total.get(key):
            return (QueuedReason.NO_CELL_FOR_EMBODIMENT,
                    f"no pre-flight Cell (spec.preflight: true) has embodiment {emb!r}; ask a cluster admin "
                    "to register a simulated twin of it, or submit the job without spec.preflight")
        if not self.available.get(key):
            return (QueuedReason.ALL_CELLS_UNAVAILABLE,
                    f"all {self.total[key]} pre-flight Cell(s) of {emb!r} are offline, faulted or cordoned")
        return QueuedReason.ALL_CELLS_BUSY, f"all {self.available[key]} available pre-flight Cell(s) of {emb!r} are busy"


#: Marks the census key of an embodiment's pre-flight cells: no real pool key (a name, a pair of names) equals it.
_TWIN = object()


def plan_bindings(
    jobs: Iterable[Job],
    cells: Iterable[Cell],
    now: datetime,
    heartbeat_timeout: timedelta,
    quotas: Iterable[CellQuota] = (),
    usage: Mapping[str, Usage] | None = None,
    sharing: FairSharing = DEFAULT_SHARING,
) -> SchedulePlan:
    """Bind waiting jobs to free available cells; give every other waiting job a reason.

    ``usage`` is each quota's usage by quota name (absent: none yet).
    """
    jobs = list(jobs)
    cells = list(cells)
    quotas = list(quotas)
    occupied = occupied_cells(jobs, cells)
    claimed_jobs = {cell.current_job for cell in cells if cell.current_job}
    phases = {
        cell.name: (cell, derive_cell_phase(cell, cell.name in occupied, now, heartbeat_timeout))
        for cell in cells
    }
    pools = _Pools([cell for cell, phase in phases.values() if phase is CellPhase.READY])
    census = _Census(phases)
    claimed = frozenset(k for k in claimed_jobs if k is not None)
    ledger = Ledger(quotas, (j for j in jobs if holds_cell(j, claimed)), usage or {}, now, sharing)

    queues: dict[str, list[Job]] = defaultdict(list)
    for job in sorted((j for j in jobs if j.waiting and not j.awaits_preflight), key=order_key):
        queues[ledger.tenant_of(job)].append(job)
    turns = [(ledger.rank(t), order_key(q[0]), t) for t, q in queues.items()]
    heapq.heapify(turns)
    heads = dict.fromkeys(queues, 0)

    bindings: list[Binding] = []
    entries: list[tuple[Job, QueuedReason, str]] = []
    exhausted: list[tuple[Job, QueuedReason, str]] = []
    while turns:
        _, _, tenant = heapq.heappop(turns)
        queue, head = queues[tenant], heads[tenant]
        job = queue[head]
        heads[tenant] = head + 1
        if job.key in claimed_jobs:
            # A half-done binding from a crash: wait for the repair to release the claim.
            entries.append((job, QueuedReason.WAITING_FOR_CELL_RELEASE,
                            "a Cell still holds an unfinished claim on this job; it is released shortly"))
        elif (problem := ledger.blocked(tenant, job)) is not None:
            # Usage only grows within a pass: the rest of this tenant's queue waits too.
            exhausted.extend(_quota_entry(j, census, problem) for j in queue[head:])
            continue
        elif (cell := pools.pop(job)) is not None:
            bindings.append(Binding(job, cell))
            ledger.charge(tenant)
        else:
            entries.append((job, *census.reason(job)))
        if head + 1 < len(queue):
            heapq.heappush(turns, (ledger.rank(tenant), order_key(queue[head + 1]), tenant))
    exhausted.sort(key=lambda entry: order_key(entry[0]))
    twin_entries = [(replace(job, task=None), reason, message) for job, reason, message in entries
                    if job.is_preflight]
    entries = [entry for entry in entries if not entry[0].is_preflight]
    # Twins and real cells are disjoint pools: each has its own positions, estimates and cell queues.
    positions = {**_positions(twin_entries), **_positions(entries + exhausted)}
    positions.update(_awaiting_positions(jobs, entries + exhausted, positions))
    holders = _holders(jobs, bindings, now)
    typical = typical_runs(j for j in jobs if not j.is_preflight)
    real = {name: pair for name, pair in phases.items() if not pair[0].preflight}
    latest, likely = _start_estimates(entries, holders, typical, real, now)
    at_cells = cell_queues([c for c in cells if not c.preflight], (job for job, _, _ in entries + exhausted),
                           holders, now, typical)
    at_cells.update(cell_queues([c for c in cells if c.preflight], (job for job, _, _ in twin_entries),
                                holders, now, typical))
    for_busy = [job for job, reason, _ in entries if reason is QueuedReason.ALL_CELLS_BUSY]
    reclaims = plan_reclaim(holders.values(), for_busy, cells, quotas, usage or {}, now, sharing) if for_busy else ()
    at_limit = for_busy + [job for job, _, _ in exhausted]
    if at_limit and any(q.preempt_lower_priority for q in quotas):
        reclaims += plan_within_quota(holders.values(), at_limit, cells, quotas, usage or {}, now, reclaims)
    return SchedulePlan(tuple(bindings), {
        key: replace(entry, latest_start=latest[key], likely_start=likely.get(key, latest[key]))
        if key in latest else entry
        for key, entry in positions.items()
    }, at_cells, reclaims)


def _holders(jobs: list[Job], bindings: list[Binding], now: datetime) -> dict[str, Job]:
    """Cell name -> the job holding it after this pass's bindings."""
    holders = {job.cell_name: job for job in jobs if job.active and job.cell_name}
    holders.update({b.cell.name: replace(b.job, bound_at=now, cell_name=b.cell.name) for b in bindings})
    return holders


def _start_estimates(
    entries: list[tuple[Job, QueuedReason, str]], holders: Mapping[str, Job], typical: Mapping[str, timedelta],
    phases: Mapping[str, tuple[Cell, CellPhase]], now: datetime,
) -> tuple[dict[str, datetime], dict[str, datetime]]:
    """The latest and the likely start of each job that waits for busy cells (``estimate``), after this pass's bindings."""
    busy = [job for job, reason, _ in entries if reason is QueuedReason.ALL_CELLS_BUSY]
    if not busy:
        return {}, {}
    available = [cell for cell, phase in phases.values() if is_available(phase)]
    likely = likely_occupancy(typical)
    return (queue_starts(busy, seats(available, holders, now)),
            queue_starts(busy, seats(available, holders, now, likely), likely))


def _quota_entry(job: Job, census: _Census, problem: str) -> tuple[Job, QueuedReason, str]:
    """A missing or unavailable cell is the more actionable fact; else the quota is why."""
    reason, message = census.reason(job)
    if reason is QueuedReason.ALL_CELLS_BUSY:
        return job, QueuedReason.QUOTA_EXHAUSTED, problem
    return job, reason, message


def _positions(entries: list[tuple[Job, QueuedReason, str]]) -> dict[str, QueueEntry]:
    """Each waiting job's place among the jobs competing for its cells, in the order given.

    A job with a task competes with the jobs of its task and with untasked jobs of
    its embodiment; an untasked job with every job of its embodiment.
    """
    queued: dict[str, QueueEntry] = {}
    ahead_any: dict[str, int] = defaultdict(int)
    ahead_untasked: dict[str, int] = defaultdict(int)
    ahead_task: dict[tuple[str, str], int] = defaultdict(int)
    for job, reason, message in entries:
        emb = job.embodiment
        if job.task is None:
            position = ahead_any[emb] + 1
            ahead_untasked[emb] += 1
        else:
            position = ahead_task[(emb, job.task)] + ahead_untasked[emb] + 1
            ahead_task[(emb, job.task)] += 1
        ahead_any[emb] += 1
        queued[job.key] = QueueEntry(reason, position, message)
    return queued


def _awaiting_positions(jobs: list[Job], ahead: list[tuple[Job, QueuedReason, str]],
                        planned: Mapping[str, QueueEntry]) -> dict[str, QueueEntry]:
    """The jobs waiting for their pre-flight's verdict: behind every job waiting for a cell (they are
    not in the running for one yet), each told what its pre-flight is doing."""
    awaiting = sorted((j for j in jobs if j.waiting and j.awaits_preflight), key=order_key)
    if not awaiting:
        return {}
    entries = []
    for job in awaiting:
        name = job.preflight_job
        found = planned.get(f"{job.namespace}/{name}") if name else None
        if name is None:
            doing = "its pre-flight on a simulated twin is being created"
        elif found is not None:
            doing = f"its pre-flight job {name} waits for a pre-flight cell ({found.reason}: {found.message})"
        else:
            doing = f"its pre-flight job {name} runs on a simulated twin"
        entries.append((job, QueuedReason.PREFLIGHT_RUNNING,
                        f"{doing}; the job joins the queue for a real cell, in its place, once it passes"))
    placed = _positions(ahead + entries)
    return {job.key: placed[job.key] for job, _, _ in entries}


def choose_cell(
    job: Job, cells: Iterable[Cell], now: datetime, heartbeat_timeout: timedelta
) -> Cell | None:
    """The cell ``job`` would get if it were alone in the queue (for CLIs and tests)."""
    plan = plan_bindings([job], cells, now, heartbeat_timeout)
    return plan.bindings[0].cell if plan.bindings else None
