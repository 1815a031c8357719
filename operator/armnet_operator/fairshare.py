"""Fair share between tenants: who may take a cell, who is next, which borrowed cell goes back.

Pure: a ``Ledger`` is built from a snapshot (quotas, the jobs holding cells, each
quota's usage) and answers the scheduler's three questions about a tenant: is it
blocked by its quota (and why, in words), does its next cell need borrowing, and
its rank among the tenants competing for the same cells. ``plan_reclaim`` says
which borrowing jobs should stop at their next episode boundary so a waiting
owner gets its nominal cell back; ``plan_within_quota`` which of a tenant's own
jobs a higher-priority job of that tenant preempts, where its quota allows it.
Nothing here writes; the scheduler decides.

The rules, in Kueue's terms:

- A tenant is a CellQuota; a job belongs to the quota of its namespace and
  embodiment whose task is the job's task, else the one without a task.
- Pre-flights (``armnet.io/preflight-for``) are unmanaged too: they only ever run on
  simulated twins (``Cell.preflight``), which no quota shares out.
- A namespace without any CellQuota is not rationed (today's behaviour: no
  limit, weight 1, no recorded usage): all its jobs form one unmanaged tenant.
  A namespace with CellQuotas is rationed: a job none of them covers waits.
- A tenant may hold ``nominalCells``; beyond that it borrows, only while its
  cohort (same cohort name, same embodiment) has idle nominal cells, and at
  most ``borrowingLimit`` cells.
- Among tenants that can take a cell, those within their nominal share go
  first; then the lowest ``(decayed usage + entry penalty x cells held) / weight``;
  ties go to the tenant whose next job comes first by priority, then age.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime

from .model import Cell, Job
from .quota import (
    DEFAULT_SHARING,
    CellQuota,
    FairSharing,
    Usage,
    accrue_usage,
    credits_left,
    period_end,
)

UNMANAGED = ""
"""The tenant key of jobs from namespaces without any CellQuota."""
_NO_USAGE = Usage()


def _uncovered(namespace: str) -> str:
    return f"{namespace}/"


def index_quotas(quotas: Iterable[CellQuota]) -> tuple[dict[str, CellQuota], list[str]]:
    """Quotas by name, and a problem per quota that duplicates another's tenant and scope.

    Two quotas for the same namespace, embodiment and task would make the
    share ambiguous: the one whose name sorts first counts, the others are
    reported (and ignored) until fixed.
    """
    kept: dict[str, CellQuota] = {}
    seen: dict[tuple[str, str, str | None], str] = {}
    problems: list[str] = []
    for quota in sorted(quotas, key=lambda q: q.name):
        scope = (quota.namespace, quota.embodiment, quota.task)
        if scope in seen:
            problems.append(
                f"CellQuota {quota.name!r} is ignored: {seen[scope]!r} already covers namespace "
                f"{quota.namespace!r}, embodiment {quota.embodiment!r}"
                + (f", task {quota.task!r}" if quota.task else "") + "; delete one of them")
            continue
        seen[scope] = quota.name
        kept[quota.name] = quota
    return kept, problems


@dataclass
class _Account:
    quota: CellQuota
    used: int = 0
    usage: Usage = _NO_USAGE


class Ledger:
    """Cells held per tenant and per cohort, updated as the scheduler grants cells."""

    def __init__(
        self,
        quotas: Iterable[CellQuota],
        holders: Iterable[Job],
        usage: Mapping[str, Usage],
        now: datetime,
        sharing: FairSharing,
    ) -> None:
        self.now = now
        self.penalty = sharing.entry_penalty.total_seconds()
        by_name, self.problems = index_quotas(quotas)
        self.accounts = {name: _Account(q, 0, usage.get(name, _NO_USAGE)) for name, q in by_name.items()}
        self._scope: dict[tuple[str, str, str | None], str] = {
            (q.namespace, q.embodiment, q.task): name for name, q in by_name.items()}
        self._rationed = {q.namespace for q in by_name.values()}
        self.cohort_nominal: dict[tuple[str, str], int] = defaultdict(int)
        self.cohort_used: dict[tuple[str, str], int] = defaultdict(int)
        for account in self.accounts.values():
            pool = _cohort_pool(account.quota)
            if pool is not None:
                self.cohort_nominal[pool] += account.quota.nominal_cells
        for job in holders:
            self.charge(self.tenant_of(job))

    def tenant_of(self, job: Job) -> str:
        """The quota name that governs ``job``, ``UNMANAGED``, or the uncovered key of its namespace.

        A pre-flight (``preflight``) is unmanaged: it runs on a simulated twin, never on a
        real cell, so no quota rations it (and as no quota's job, nothing preempts it).
        """
        if job.namespace not in self._rationed or job.is_preflight:
            return UNMANAGED
        if job.task is not None:
            name = self._scope.get((job.namespace, job.embodiment, job.task))
            if name is not None:
                return name
        return self._scope.get((job.namespace, job.embodiment, None)) or _uncovered(job.namespace)

    def charge(self, tenant: str) -> None:
        """One more cell held by ``tenant`` (a grant, or a job found holding one)."""
        account = self.accounts.get(tenant)
        if account is None:
            return
        account.used += 1
        pool = _cohort_pool(account.quota)
        if pool is not None:
            self.cohort_used[pool] += 1

    def release(self, tenant: str) -> None:
        """One cell fewer held by ``tenant`` (a reclaimed job)."""
        account = self.accounts.get(tenant)
        if account is None:
            return
        account.used -= 1
        pool = _cohort_pool(account.quota)
        if pool is not None:
            self.cohort_used[pool] -= 1

    def borrowing(self, tenant: str) -> bool:
        """Whether the tenant's next cell would be beyond its nominal share."""
        account = self.accounts.get(tenant)
        return account is not None and account.used >= account.quota.nominal_cells

    def score(self, tenant: str) -> float:
        """Weighted usage: lower goes first. The unmanaged tenant records none."""
        account = self.accounts.get(tenant)
        if account is None:
            return 0.0
        held = account.usage.decayed_cell_seconds + self.penalty * account.used
        return held / account.quota.weight

    def rank(self, tenant: str) -> tuple[bool, float]:
        return self.borrowing(tenant), self.score(tenant)

    def blocked(self, tenant: str, job: Job) -> str | None:
        """Why the tenant may take no cell now (the QuotaExhausted message), or None."""
        if tenant == UNMANAGED:
            return None
        account = self.accounts.get(tenant)
        if account is None:
            scope = f"embodiment {job.embodiment!r}" + (f", task {job.task!r}" if job.task else "")
            names = sorted(n for n, a in self.accounts.items() if a.quota.namespace == job.namespace)
            return (f"no CellQuota of namespace {job.namespace!r} covers {scope} (it has "
                    f"{', '.join(names)}); ask your cluster admin for one, or change spec.embodiment")
        quota, used = account.quota, account.used
        left = credits_left(quota, account.usage, self.now)
        if left is not None and left <= 0 and quota.period is not None:
            # A message for people, not a time on the wire: a period ends on a whole minute.
            return (f"CellQuota {quota.name!r}: the {quota.credits_cell_hours:g} cell-hour(s) of this "
                    f"{quota.period.lower()} are used up; new credits at "
                    f"{period_end(self.now, quota.period):%Y-%m-%dT%H:%MZ}")
        if used < quota.nominal_cells:
            return None
        held = f"CellQuota {quota.name!r} gives {quota.nominal_cells} nominal {quota.embodiment!r} cell(s)"
        pool = _cohort_pool(quota)
        if pool is None:
            return f"{held} and {used} are in use (no cohort to borrow from)"
        if quota.borrowing_limit is not None and used >= quota.nominal_cells + quota.borrowing_limit:
            return f"{held} + {quota.borrowing_limit} borrowed and all {used} are in use"
        if self.cohort_used[pool] >= self.cohort_nominal[pool]:
            return f"{held}, all {used} in use, and cohort {quota.cohort!r} has no idle cell to lend"
        return None


def _cohort_pool(quota: CellQuota) -> tuple[str, str] | None:
    """Quotas lend to each other within one cohort and one embodiment (cells are not fungible)."""
    return None if quota.cohort is None else (quota.cohort, quota.embodiment)


def holds_cell(job: Job, claimed: frozenset[str] | set[str]) -> bool:
    """A job holds a cell while it is dispatched or running, or while a cell's claim names it."""
    return (job.active and job.cell_name is not None) or job.key in claimed


@dataclass(frozen=True)
class Reclaim:
    """Ask ``job`` to stop at its next episode boundary so ``for_job`` gets its cell.

    ``reason``: ``reclaim`` (``job`` borrows a cell of ``for_job``'s tenant) or ``priority``
    (both of one tenant, whose quota lets a higher priority preempt a lower one).
    """

    job: Job
    cell: str
    quota: str
    for_job: Job
    message: str
    reason: str = "reclaim"


def plan_reclaim(
    holders: Iterable[Job],
    waiting: Iterable[Job],
    cells: Iterable[Cell],
    quotas: Iterable[CellQuota],
    usage: Mapping[str, Usage],
    now: datetime,
    sharing: FairSharing = DEFAULT_SHARING,
) -> tuple[Reclaim, ...]:
    """Which borrowing jobs to stop so owners waiting within their nominal share get cells back.

    ``holders`` are the jobs holding cells after this pass's bindings; ``waiting``
    the jobs the pass left waiting for a busy cell. An owner qualifies while its
    quota holds fewer than ``nominalCells``; a victim is a job of another quota of
    the same cohort and embodiment that holds more than its nominal share, on a
    cell the owner's job can use. Victims go most-over-share tenant first, then
    lowest priority, then most recently bound (Kueue's order). A borrowing job
    already asked to stop (``spec.cancel``, or preempted already) counts as a cell
    on its way back, so the decision is the same when repeated on the next pass.
    """
    holders = [j for j in holders if j.cell_name is not None]
    ledger = Ledger(quotas, holders, usage, now, sharing)
    cell_task = {c.name: c.task for c in cells}
    candidates: dict[tuple[str, str], list[Job]] = defaultdict(list)
    for job in holders:
        account = ledger.accounts.get(ledger.tenant_of(job))
        pool = None if account is None else _cohort_pool(account.quota)
        if pool is not None:
            candidates[pool].append(job)
    taken: set[str] = set()
    decisions: list[Reclaim] = []
    for owner in sorted(waiting, key=lambda j: j.queue_order):
        tenant = ledger.tenant_of(owner)
        account = ledger.accounts.get(tenant)
        if account is None or account.used >= account.quota.nominal_cells:
            continue
        pool = _cohort_pool(account.quota)
        if pool is None:
            continue
        victim = _victim(candidates[pool], tenant, owner, ledger, cell_task, taken)
        if victim is None:
            continue
        taken.add(victim.key)
        victim_tenant = ledger.tenant_of(victim)
        ledger.release(victim_tenant)
        ledger.charge(tenant)
        if not (victim.cancel or victim.preempting):
            decisions.append(Reclaim(victim, victim.cell_name or "", victim_tenant, owner,
                                     f"cell {victim.cell_name} is borrowed by CellQuota {victim_tenant!r}; "
                                     f"its owner {account.quota.name!r} has job {owner.key} waiting"))
    return tuple(decisions)


def _victim(
    jobs: list[Job], owner_tenant: str, owner: Job, ledger: Ledger,
    cell_task: Mapping[str, str | None], taken: set[str],
) -> Job | None:
    best: Job | None = None
    best_key: tuple[bool, float, int, float, str] | None = None
    for job in jobs:
        tenant = ledger.tenant_of(job)
        account = ledger.accounts[tenant]
        if (job.key in taken or tenant == owner_tenant or account.used <= account.quota.nominal_cells
                or (owner.task is not None and cell_task.get(job.cell_name or "") != owner.task)):
            continue
        bound = job.bound_at.timestamp() if job.bound_at else 0.0
        key = (not (job.cancel or job.preempting), -ledger.score(tenant), job.priority, -bound, job.key)
        if best_key is None or key < best_key:
            best, best_key = job, key
    return best


def plan_within_quota(
    holders: Iterable[Job],
    waiting: Iterable[Job],
    cells: Iterable[Cell],
    quotas: Iterable[CellQuota],
    usage: Mapping[str, Usage],
    now: datetime,
    decided: Iterable[Reclaim] = (),
) -> tuple[Reclaim, ...]:
    """Which of a tenant's running jobs its waiting jobs of higher priority preempt (Kueue's
    ``withinClusterQueue: LowerPriority``), where the tenant's CellQuota says so.

    Only within one quota: a tenant sets its own ``spec.priority``, so a priority says
    nothing across tenants. ``waiting`` are the jobs left waiting for a busy cell or at
    their quota's limit (a job out of credits preempts nothing: a freed cell would not
    be its). ``decided`` are this pass's reclaims: their victims are taken and the jobs
    they serve need nothing more. Each waiting job, highest priority first, then oldest,
    preempts at most one job of strictly lower priority on a cell it can use: the lowest
    priority, then the most recently bound. A job already asked to stop (cancelled or
    preempting) counts as the cell on its way back for the highest-priority waiting job
    it could serve, so the decision is the same when repeated on the next pass.
    """
    decided = list(decided)
    by_name, _ = index_quotas(quotas)
    ledger = Ledger(by_name.values(), (), usage, now, DEFAULT_SHARING)
    cell_task = {c.name: c.task for c in cells}
    taken = {r.job.key for r in decided}
    served = {r.for_job.key for r in decided}
    mine: dict[str, list[Job]] = defaultdict(list)
    for job in holders:
        if job.cell_name is not None and job.key not in taken:
            mine[ledger.tenant_of(job)].append(job)
    decisions: list[Reclaim] = []
    for owner in sorted(waiting, key=lambda j: j.queue_order):
        tenant = ledger.tenant_of(owner)
        quota = by_name.get(tenant)
        if owner.key in served or quota is None or not quota.preempt_lower_priority:
            continue
        left = credits_left(quota, usage.get(tenant, _NO_USAGE), now)
        if left is not None and left <= 0:
            continue
        usable = [j for j in mine[tenant] if j.key not in taken and j.priority < owner.priority
                  and (owner.task is None or cell_task.get(j.cell_name or "") == owner.task)]
        if not usable:
            continue
        victim = min(usable, key=lambda j: (not (j.cancel or j.preempting), j.priority,
                                            -(j.bound_at.timestamp() if j.bound_at else 0.0), j.key))
        taken.add(victim.key)
        if not (victim.cancel or victim.preempting):
            decisions.append(Reclaim(
                victim, victim.cell_name or "", tenant, owner,
                f"job {owner.key} of CellQuota {tenant!r} has priority {owner.priority}, above this job's "
                f"{victim.priority} (the quota's preemption.withinQuota is LowerPriority)", "priority"))
    return tuple(decisions)


@dataclass(frozen=True)
class Standing:
    """A quota's standing for its status: what it holds, borrows and waits for, and its usage."""

    cells_in_use: int
    borrowed_cells: int
    waiting_jobs: int
    usage: Usage


def plan_standings(
    jobs: Iterable[Job],
    cells: Iterable[Cell],
    quotas: Iterable[CellQuota],
    usage: Mapping[str, Usage],
    now: datetime,
    sharing: FairSharing = DEFAULT_SHARING,
) -> dict[str, Standing]:
    """Each quota's standing at ``now``, its usage accrued since it was last written.

    The cells held now are taken as held since the last write: the writer calls
    this every pass (seconds apart), so the error is one pass of a change.
    """
    jobs = list(jobs)
    claimed = {c.current_job for c in cells if c.current_job}
    ledger = Ledger(quotas, (j for j in jobs if holds_cell(j, claimed)), usage, now, sharing)
    waiting: dict[str, int] = defaultdict(int)
    for job in jobs:
        if job.waiting and job.key not in claimed:
            waiting[ledger.tenant_of(job)] += 1
    return {
        name: Standing(a.used, max(0, a.used - a.quota.nominal_cells), waiting[name],
                       accrue_usage(a.usage, a.used, now, sharing.half_life, a.quota.period))
        for name, a in ledger.accounts.items()
    }


__all__ = ["UNMANAGED", "Ledger", "Reclaim", "Standing", "holds_cell", "index_quotas", "plan_reclaim",
           "plan_standings", "plan_within_quota"]
