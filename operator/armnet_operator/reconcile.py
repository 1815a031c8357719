"""One reconcile pass: plan on a snapshot, then write, in a safe order.

This is the one writer of bindings. It is synchronous and talks to the API
through the small ``Api`` protocol, so the same code runs in the operator
(real API server, in a worker thread) and in the property test (an in-memory
world with the same optimistic-concurrency rules). It must never import kopf.

Order inside a pass: lifecycle repairs first, then bindings (claim the Cell,
then bind the job; undo the claim if the job moved), then finalizers and queue
status. A new job's finalizer is written after its bind (or just before its
queue status), never in a round of its own before the bindings and never before
its claim: submit->bound costs two writes, not three. The window this opens (a
job deleted between its bind and its finalizer vanishes at once) is covered by
the repair: its cell then names a job that no longer exists and is released
after the claim grace, and until then nothing else is bound to it.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, MutableMapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta
from functools import partial
from typing import Any

from armnet_core.times import kube_time

from . import patches
from .artifact_removal import outputs_prefix
from .cell_checks import check_cell, check_cells
from .derived_jobs import (
    conclude_preflight,
    owner_gone,
    preempt,
    requeue_preempted,
    start_preflight,
)
from .duty_cycle import DutyState
from .errors import Conflict, NotFound, ResourceMissing, TransientError
from .health import derive_cell_phase
from .lifecycle import (
    Action,
    AddFinalizer,
    CancelPreflight,
    ConcludePreflight,
    DeleteJob,
    FinishJob,
    ReleaseCell,
    RemoveFinalizer,
    RepairStatus,
    RequestCancel,
    RequeueJob,
    RequeuePreempted,
    SetCellPhase,
    StartPreflight,
    plan_active_job,
    plan_lifecycle,
    release_reason,
)
from .model import Cell, CellPhase, CellQueue, Job, JobPhase, Timing
from .parsing import parse_cell, parse_job
from .pass_io import Api, Failure, Outcome, count_failure, post_event, write
from .quota import QuotaObject, Usage
from .quota_writes import current_usage, plan_quota_writes, quotas_in_force
from .scheduling import Binding, QueueEntry, plan_bindings

log = logging.getLogger(__name__)


@dataclass
class Memory:
    """What the writer remembers between passes (lost on restart, which is fine)."""

    queue_written_at: MutableMapping[str, datetime] = field(default_factory=dict)
    seen_phases: MutableMapping[str, JobPhase | None] = field(default_factory=dict)
    failing: MutableMapping[str, str] = field(default_factory=dict)
    """Objects a pass could not handle, by subject key, with the error last reported for each."""
    quota_usage: MutableMapping[str, Usage] = field(default_factory=dict)
    """Each CellQuota's usage as this replica last wrote it (until the watch delivers it)."""
    quota_shown: MutableMapping[str, dict[str, Any]] = field(default_factory=dict)
    """Each CellQuota's status as last written, apart from its usage: a change is written at once."""
    cell_queue_written: MutableMapping[str, tuple[CellQueue, datetime]] = field(default_factory=dict)
    """Each Cell's ``status.queue`` as this replica last wrote it, and when (until the watch shows it)."""


@dataclass(frozen=True)
class Limits:
    position_refresh: timedelta = timedelta(seconds=5)
    max_queue_writes: int = 200
    parallel_binds: int = 1
    max_queue_tasks: int = 10_000
    """Jobs whose finalizer or queue status one pass writes; the rest wait for the next pass."""
    queue_seconds: float | None = None
    """Time a pass may spend on finalizers and queue status; what is left waits for the next pass."""
    quota_refresh: timedelta = timedelta(seconds=30)
    """A CellQuota's usage is written at least this often while nothing else in its status changes."""


def reconcile_once(
    jobs: Iterable[Job],
    cells: Iterable[Cell],
    now: datetime,
    timing: Timing,
    api: Api,
    memory: Memory,
    limits: Limits = Limits(),
    quotas: Sequence[QuotaObject] = (),
) -> Outcome:
    """One pass. ``quotas`` are the CellQuotas in scope (none: no tenant is rationed)."""
    outcome = Outcome()
    in_force, _ = quotas_in_force(quotas)
    usage = current_usage(quotas, memory.quota_usage)
    jobs, cells = list(jobs), check_cells(cells)
    try:
        actions = plan_lifecycle(jobs, cells, now, timing)
    except Exception:  # noqa: BLE001 - find the objects it fails on, skip them, plan the rest
        jobs, cells, outcome.failed = screen(jobs, cells, now, timing)
        actions = plan_lifecycle(jobs, cells, now, timing)
    _post_transitions(jobs, memory, api)
    by_key = {j.key: j for j in jobs}
    by_name = {c.name: c for c in cells}
    groups: dict[str, list[Action]] = defaultdict(list)
    for action in actions:
        groups[_subject(action)].append(action)
    finalizing = {k: g[0] for k, g in groups.items() if len(g) == 1 and isinstance(g[0], AddFinalizer)}
    finalize = {a.job.key for a in finalizing.values() if isinstance(a, AddFinalizer)}
    work = [_guarded(k, _first_subject(g), partial(_apply_group, g, now, timing, api))
            for k, g in groups.items() if k not in finalizing]
    for result in _parallel(limits.parallel_binds, work):
        outcome.merge(result)
    # Re-read what we wrote from the responses, so the scheduler works on current
    # resourceVersions: a cell freed by a finished job takes the next one in this pass.
    for key in outcome.deleted:
        by_key.pop(key, None)
    by_key.update(outcome.jobs_written)
    by_name.update(outcome.cells_written)
    try:
        plan = plan_bindings(by_key.values(), by_name.values(), now, timing.heartbeat_timeout, in_force, usage)
    except Exception:  # noqa: BLE001 - as above: the pass goes on without the objects it fails on
        kept_jobs, kept_cells, failed = screen(by_key.values(), by_name.values(), now, timing)
        outcome.failed.update(failed)
        by_key = {j.key: j for j in kept_jobs}
        by_name = {c.name: c for c in kept_cells}
        plan = plan_bindings(kept_jobs, kept_cells, now, timing.heartbeat_timeout, in_force, usage)
    # Bindings touch disjoint cells and jobs, so they may run side by side: the
    # preconditions, not the ordering, are what keep them safe.
    bound_before = len(outcome.bound)
    binds = [_guarded(f"job:{b.job.key}", b.job, partial(_bind, b, now, timing.heartbeat_timeout, api))
             for b in plan.bindings]
    for result in _parallel(limits.parallel_binds, binds):
        outcome.merge(result)
    # Finalizers after the binds: off the submit->bound path. A job whose bind failed
    # gets its finalizer next pass (it changed under us; this write would conflict).
    preempts = [_guarded(f"job:{r.job.key}", r.job, partial(preempt, r, now, timing, api)) for r in plan.reclaims]
    for result in _parallel(limits.parallel_binds, preempts):
        outcome.merge(result)
    finalize.difference_update(b.job.key for b in plan.bindings)
    finalize.update(j.key for j, _ in outcome.bound[bound_before:] if not j.has_finalizer)
    by_key.update(outcome.jobs_written)
    outcome.queue = dict(plan.queued)
    due = dict(_queue_writes_due(plan.queued, by_key, now, memory, limits))
    # Bounded per pass (in time, and in count), bound jobs' finalizers first, then in queue
    # order: a burst of new jobs then costs several short passes, not one long one, so a
    # job that arrives meanwhile for a free cell waits for a short pass, not for the burst.
    order = sorted(k for k in finalize if k not in plan.queued)
    order += [k for k in plan.queued if k in finalize or k in due]
    outcome.more = len(order) > limits.max_queue_tasks
    deadline = None if limits.queue_seconds is None else time.monotonic() + limits.queue_seconds
    work = [_paced(deadline, _guarded(f"job:{k}", by_key[k],
                                      partial(_queue, by_key[k], k in finalize, due.get(k), now, api)))
            for k in order[: limits.max_queue_tasks]]
    for result in _parallel(limits.parallel_binds, work):
        outcome.merge(result)
        outcome.more = outcome.more or result.more
    for key in outcome.jobs_written:
        if key in plan.queued:
            memory.queue_written_at[key] = now
    by_key.update(outcome.jobs_written)
    if quotas or memory.quota_shown:
        _write_quotas(by_key.values(), by_name.values(), quotas, now, api, memory, limits, outcome)
    _write_cell_queues(by_name.values(), plan.cell_queues, now, api, memory, outcome,
                       skip=frozenset(outcome.cells_written))
    _report_failures(outcome, {**{f"job:{k}": j for k, j in by_key.items()},
                               **{f"cell:{n}": c for n, c in by_name.items()}}, memory, api, now)
    return outcome


#: The least time between two writes of one Cell's ``status.queue``: an advisory figure for a
#: person, written beside the claims and releases the operator guards with the Cell's
#: resourceVersion (each write of it makes the next guarded write of the Cell conflict
#: until the watch shows it).
CELL_QUEUE_REFRESH = timedelta(seconds=10)


def _write_cell_queues(cells: Iterable[Cell], planned: Mapping[str, CellQueue], now: datetime, api: Api,
                       memory: Memory, outcome: Outcome, skip: frozenset[str]) -> None:
    """Each Cell's ``status.queue`` that moved (last in a pass: binds and job status go first).

    Moved: the count of waiting jobs changed, or a free time moved by ``ESTIMATE_STEP`` or
    appeared or vanished, against what this replica last wrote (the watch may not show it
    yet: comparing with the listed Cell would write it again every pass until it does), or
    against the listed Cell when this replica wrote none. At most once per
    ``CELL_QUEUE_REFRESH`` per cell; never for a cell this pass already wrote (its claim or
    release holds its resourceVersion). A failed write is retried later and never stops
    scheduling.
    """
    known = set()
    for cell in cells:
        known.add(cell.name)
        queue = planned.get(cell.name)
        written, at = memory.cell_queue_written.get(cell.name, (cell.queue, None))
        if queue is None or cell.name in skip or not _cell_queue_moved(written, queue) \
                or (at is not None and now - at < CELL_QUEUE_REFRESH):
            continue
        try:
            api.patch(patches.cell_queue(cell.name, queue))
        except NotFound:
            continue
        except TransientError as error:
            count_failure(error, outcome)
            continue
        except Exception as error:  # noqa: BLE001 - an advisory summary (RBAC, an old CRD) never stops scheduling
            log.warning("queue summary of Cell %s not written, retrying next pass: %s", cell.name, error)
            continue
        outcome.writes += 1
        memory.cell_queue_written[cell.name] = (queue, now)
    for stale in [name for name in memory.cell_queue_written if name not in known]:
        del memory.cell_queue_written[stale]


def _cell_queue_moved(written: CellQueue, planned: CellQueue) -> bool:
    return written.waiting_jobs != planned.waiting_jobs \
        or _estimate_moved(written.likely_free, planned.likely_free) \
        or _estimate_moved(written.latest_free, planned.latest_free)


def _write_quotas(jobs: Iterable[Job], cells: Iterable[Cell], quotas: Sequence[QuotaObject], now: datetime,
                  api: Api, memory: Memory, limits: Limits, outcome: Outcome) -> None:
    """Each CellQuota's status that is due (last: binds and queue status go first).

    A quota that cannot be read or is ignored is logged once per distinct
    problem and says why in ``status.message``. A failed write (even a
    forbidden one: an RBAC without ``cellquotas/status``) is logged and retried
    next pass; it never stops scheduling.
    """
    ignored = quotas_in_force(quotas)[1]
    outcome.quotas_ignored = len(ignored)
    by_name = {q.name: q for q in quotas}
    for name, problem in ignored.items():
        key = f"quota:{name}"
        if memory.failing.get(key) != problem:
            memory.failing[key] = problem
            log.error("%s", problem)
            # Once per distinct problem: where `kubectl describe cellquota` shows it.
            post_event(api, by_name[name], "Warning", "QuotaIgnored", problem)
    for key in [k for k in memory.failing if k.startswith("quota:") and k.removeprefix("quota:") not in ignored]:
        del memory.failing[key]
    known = {q.name for q in quotas}
    for stale in [n for n in memory.quota_shown if n not in known]:
        memory.quota_shown.pop(stale, None)
        memory.quota_usage.pop(stale, None)
    writes = plan_quota_writes(jobs, cells, quotas, memory.quota_usage, memory.quota_shown, now,
                               limits.quota_refresh)
    for quota_write in writes:
        try:
            api.patch(patches.quota_status(quota_write.name, quota_write.status))
        except NotFound:
            continue
        except TransientError as error:
            count_failure(error, outcome)
            continue
        except Exception as error:  # noqa: BLE001 - a quota's status (its CRD gone, RBAC) never stops scheduling
            log.error("status of CellQuota %s not written, retrying next pass: %s", quota_write.name, error)
            continue
        outcome.writes += 1
        memory.quota_shown[quota_write.name] = {k: v for k, v in quota_write.status.items() if k != "usage"}
        if quota_write.usage is not None:
            memory.quota_usage[quota_write.name] = quota_write.usage


def screen(
    jobs: Iterable[Job], cells: Iterable[Cell], now: datetime, timing: Timing
) -> tuple[list[Job], list[Cell], dict[str, Failure]]:
    """Set aside every object the decisions fail on, and everything tied to it.

    Runs only when planning the whole snapshot raised (so it costs nothing in
    the normal pass). Each job and each cell is planned alone (lifecycle and scheduling on
    it and its counterpart): one that raises is a failure of that object, not
    of the pass. Objects tied to a failed one by a claim or a ``cellName`` are
    left out of this pass too, so the rest never acts on half a binding (a
    cell whose claiming job is skipped must not look abandoned).
    """
    jobs, cells = list(jobs), list(cells)
    cell_by_name = {c.name: c for c in cells}
    failed: dict[str, Failure] = {}
    for cell in cells:
        error = _trial(partial(plan_lifecycle, [], [cell], now, timing)) or _trial(
            partial(plan_bindings, [], [cell], now, timing.heartbeat_timeout))
        if error is not None:
            failed[f"cell:{cell.name}"] = Failure(cell, error)
    for job in jobs:
        mine = [c for c in (cell_by_name.get(job.cell_name or ""),) if c is not None]
        error = _trial(partial(plan_lifecycle, [job], mine, now, timing)) or _trial(
            partial(plan_bindings, [job], mine, now, timing.heartbeat_timeout))
        if error is not None:
            failed[f"job:{job.key}"] = Failure(job, error)
    skipped = set(failed)
    while True:
        tied = {f"cell:{c.name}" for c in cells if f"job:{c.current_job}" in skipped}
        tied |= {f"job:{j.key}" for j in jobs if j.cell_name and f"cell:{j.cell_name}" in skipped}
        tied |= {f"job:{c.current_job}" for c in cells if f"cell:{c.name}" in skipped and c.current_job}
        if tied <= skipped:
            break
        skipped |= tied
    return ([j for j in jobs if f"job:{j.key}" not in skipped],
            [c for c in cells if f"cell:{c.name}" not in skipped], failed)


def _trial(decide: Callable[[], object]) -> str | None:
    try:
        decide()
    except Exception as error:  # noqa: BLE001 - any failure on one object is reported and skipped
        return _describe(error)
    return None


def _describe(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"[:512]


def _paced(deadline: float | None, task: Callable[[], Outcome]) -> Callable[[], Outcome]:
    """Skip the task once the pass is past its queue-writing budget; the next pass does it."""
    def run() -> Outcome:
        if deadline is not None and time.monotonic() > deadline:
            return Outcome(more=True)
        return task()
    return run


def _first_subject(actions: list[Action]) -> Job | Cell:
    action = actions[0]
    return action.cell if isinstance(action, ReleaseCell | SetCellPhase) else action.job


def _guarded(key: str, subject: Job | Cell, task: Callable[[], Outcome]) -> Callable[[], Outcome]:
    """The writes for one object; an unexpected error fails that object only, not the pass."""
    def run() -> Outcome:
        try:
            return task()
        except ResourceMissing:
            raise
        except Exception as error:  # noqa: BLE001 - one bad object must never stop scheduling
            outcome = Outcome()
            outcome.failed[key] = Failure(subject, _describe(error))
            return outcome
    return run


def _report_failures(outcome: Outcome, subjects: Mapping[str, Job | Cell], memory: Memory, api: Api,
                     now: datetime) -> None:
    """Log, Event and condition for each new failure; a ``Reconciled`` condition again once it recovers.

    Reported once per distinct error, not every pass: a stuck object must not
    flood the log or the API server.
    """
    for key, failure in outcome.failed.items():
        if memory.failing.get(key) == failure.error:
            continue
        memory.failing[key] = failure.error
        log.error("reconcile of %s %s failed; skipped it, scheduling the rest: %s",
                  failure.kind, failure.name, failure.error)
        message = f"the operator could not reconcile this object and skips it: {failure.error}"
        post_event(api, failure.subject, "Warning", "ReconcileFailed", message)
        latest = subjects.get(key, failure.subject)
        if isinstance(latest, Job):
            _mark(api, latest, False, message, now, outcome)
    for key in [k for k in memory.failing if k not in outcome.failed and k in subjects]:
        del memory.failing[key]
        subject = subjects.get(key)
        if isinstance(subject, Job):
            log.info("%s reconciles again", subject.key)
            _mark(api, subject, True, "the operator reconciles this job again", now, outcome)


def _mark(api: Api, job: Job, ok: bool, message: str, now: datetime, outcome: Outcome) -> None:
    try:
        write(api, patches.mark_reconciled(job, ok, message, now), outcome)
    except Exception as error:  # noqa: BLE001 - the Event and the log already carry the failure
        log.debug("Reconciled condition not written on %s: %s", job.key, error)


def _parallel(width: int, tasks: Sequence[Callable[[], Outcome]]) -> list[Outcome]:
    if width <= 1 or len(tasks) <= 1:
        return [task() for task in tasks]
    with ThreadPoolExecutor(min(width, len(tasks)), thread_name_prefix="armnet-write") as pool:
        return list(pool.map(lambda task: task(), tasks))


def _subject(action: Action) -> str:
    if isinstance(action, ReleaseCell | SetCellPhase):
        return f"cell:{action.cell.name}"
    return f"job:{action.job.key}"


def _apply_group(actions: list[Action], now: datetime, timing: Timing, api: Api) -> Outcome:
    """Actions on one object, in order, each on the version the previous one wrote."""
    outcome = Outcome()
    latest: Job | None = None
    for action in actions:
        if latest is not None and not isinstance(action, ReleaseCell | SetCellPhase):
            action = replace(action, job=latest)
        response = _apply(action, now, timing, api, outcome)
        if isinstance(action, DeleteJob):
            if response is not None:
                outcome.deleted.add(action.job.key)
        elif response is None:
            return outcome
        elif isinstance(action, ReleaseCell | SetCellPhase):
            outcome.cells_written[action.cell.name] = parse_cell(response)
        else:
            latest = outcome.jobs_written[action.job.key] = parse_job(response)
    return outcome


def decided_on_same_job(decided: Job, written: Job) -> bool:
    """Whether a job written without a resourceVersion precondition is still the one we decided on.

    The finalizer goes out as a JSON Patch without a resourceVersion, so it lands
    even when this replica's view of the job is stale, and its response carries a
    fresh resourceVersion. A status write chained after it with that version would
    apply a decision made on the stale view (e.g. put a job that another replica
    just bound back in the queue). Only the finalizer and the version may differ.
    """
    return replace(written, resource_version=decided.resource_version, finalizers=decided.finalizers) == decided


def _post_transitions(jobs: list[Job], memory: Memory, api: Api) -> None:
    """Events for what the agent did (start, finish), seen as phase changes between passes."""
    first = not memory.seen_phases
    current = {j.key: j.phase for j in jobs}
    if not first:
        for job in jobs:
            before = memory.seen_phases.get(job.key)
            if job.phase == before or job.phase is None:
                continue
            if job.phase is JobPhase.RUNNING:
                post_event(api, job, "Normal", "Started", f"job started on cell {job.cell_name}")
            elif job.terminal and before in (JobPhase.DISPATCHED, JobPhase.RUNNING):
                post_event(api, job, "Normal", "Finished", f"job finished: {job.phase}")
    memory.seen_phases.clear()
    memory.seen_phases.update(current)


def _apply(action: Action, now: datetime, timing: Timing, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """Write one lifecycle action; return the object as the server now has it, if written."""
    match action:
        case ReleaseCell(cell=cell, phase=phase, reason=reason, recheck=recheck, duty=duty):
            if recheck:
                rechecked = _recheck_release(cell, now, timing, api, outcome)
                if rechecked is None:
                    return None
                reason = rechecked
            log.info("releasing cell %s: %s", cell.name, reason)
            return _rest_event(api, cell, duty, write(api, patches.release_cell(cell, phase, duty), outcome))
        case SetCellPhase(cell=cell, phase=phase, duty=duty):
            return _rest_event(api, cell, duty, write(api, patches.set_cell_phase(cell, phase, duty), outcome))
        case RequeueJob(job=job, message=message):
            written = write(api, patches.requeue_job(job, message, now), outcome)
            if written is not None:
                outcome.requeued += 1
                post_event(api, job, "Warning", "Requeued", message)
            return written
        case FinishJob(job=job, phase=phase, reason=reason, error=error, recheck_cell=recheck_cell):
            if recheck_cell:
                verdict = _recheck_finish(job, now, timing, api, outcome)
                if verdict is None:
                    return None
                phase, reason, error = verdict.phase, verdict.reason, verdict.error
            written = write(api, patches.finish_job(job, phase, reason, error, now), outcome)
            if written is not None:
                kind = "Normal" if phase is JobPhase.CANCELLED and error is None else "Warning"
                post_event(api, job, kind, reason, error or f"job {phase}")
            return written
        case RequeuePreempted(job=job):
            return requeue_preempted(job, api, outcome)
        case StartPreflight(job=job):
            return start_preflight(job, now, api, outcome)
        case ConcludePreflight(job=job):
            return conclude_preflight(job, now, api, outcome)
        case CancelPreflight(job=job, recheck=recheck):
            if recheck and not owner_gone(job, api, outcome):
                return None
            written = write(api, patches.cancel_job(job), outcome)
            if written is not None:
                post_event(api, job, "Normal", "CancelRequested",
                       "the job this pre-flight was for is gone, cancelled or over")
            return written
        case RequestCancel(job=job):
            written = write(api, patches.request_cancel(job, now), outcome)
            if written is not None:
                post_event(api, job, "Normal", "CancelRequested", "asked the agent to stop the job")
            return written
        case RepairStatus(job=job):
            written = write(api, patches.repair_status(job), outcome)
            if written is not None:
                fields = ", ".join(job.status_defects)
                log.warning("repaired unreadable status field(s) of %s: %s", job.key, fields)
                post_event(api, job, "Warning", "StatusRepaired",
                       f"cleared unreadable status field(s) {fields}; the operator re-derives them")
            return written
        case AddFinalizer(job=job):
            return _add_finalizer(job, api, outcome)
        case RemoveFinalizer(job=job):
            return write(api, patches.set_finalizer(job, False), outcome)
        case DeleteJob(job=job):
            if not _outputs_settled(job, api, outcome):
                return None  # the job stays, the one pointer to its outputs: the next pass decides again
            try:
                api.delete_job(job.namespace, job.name, job.uid)
                outcome.writes += 1
            except NotFound:
                pass
            except TransientError as error:
                count_failure(error, outcome)
                return None
            return {}  # deleted: gone from this pass's view
    return None


def _outputs_settled(job: Job, api: Api, outcome: Outcome) -> bool:
    """Whether the job may be deleted as far as its stored outputs go: removed now, kept, or none.

    Decided again on the job as the server has it now, since a removal cannot be undone: a
    ``keep-artifacts`` annotation added just before the TTL, or an upload begun since, that
    the snapshot does not show yet must win. False: the job stays until a later pass.
    """
    if api.outputs_bucket is None or job.keep_artifacts:
        return True
    try:
        fresh = parse_job(api.read_job(job.namespace, job.name))
    except NotFound:
        return True
    except TransientError as error:
        count_failure(error, outcome)
        return False
    if fresh.uid != job.uid or (fresh.uploading and not job.uploading):
        return False  # another job of that name (the delete's precondition would refuse), or an upload begun since
    prefix = outputs_prefix(fresh, api.outputs_bucket)
    return prefix is None or _remove_outputs(api, fresh, prefix, outcome)


def _remove_outputs(api: Api, job: Job, prefix: str, outcome: Outcome) -> bool:
    """Remove the job's stored outputs before the job itself (``artifact_removal``); False: the store failed."""
    try:
        removed = api.remove_outputs(prefix)
    except TransientError as error:
        count_failure(error, outcome)
        outcome.outputs_removed["failed"] = outcome.outputs_removed.get("failed", 0) + 1
        return False
    outcome.outputs_removed["removed"] = outcome.outputs_removed.get("removed", 0) + 1
    log.info("removed %d stored output object(s) of %s under %s at its TTL", removed, job.key, prefix)
    return True


def _rest_event(api: Api, cell: Cell, duty: DutyState | None, written: dict[str, Any] | None) -> dict[str, Any] | None:
    """An Event on the cell when its duty cycle's rest begins (written)."""
    if written is not None and duty is not None and duty.resting_until is not None and cell.duty.resting_until is None:
        post_event(api, cell, "Normal", "Resting",
               f"duty cycle: resting until {kube_time(duty.resting_until)}; no job is bound to the cell until then")
    return written


def _recheck_release(cell: Cell, now: datetime, timing: Timing, api: Api, outcome: Outcome) -> str | None:
    """Decide a claim's release again on the claiming job as the server has it now.

    This replica's watch may lag: a job another replica bound seconds ago can
    still look queued (or not exist yet) here. Releasing its claim then would
    strand a dispatched job on a cell the scheduler sees as free. One read, only
    on this rare repair path, settles it; None means the claim stands.
    """
    namespace, _, name = (cell.current_job or "").partition("/")
    try:
        job: Job | None = parse_job(api.read_job(namespace, name)) if name else None
    except NotFound:
        job = None
    except TransientError as error:
        count_failure(error, outcome)
        return None
    return release_reason(cell, job, now, timing)


def _recheck_finish(job: Job, now: datetime, timing: Timing, api: Api, outcome: Outcome) -> FinishJob | None:
    """Decide an active job's failure again on its cell as the server has it now.

    This replica's cell watch may lag its job watch: a cell claimed for this job a
    moment ago, or heartbeating all along, can still look unclaimed or silent here,
    and failing the job on that view ends a healthy job (seen with two replicas on a
    loaded host). One read, only on this rare path, settles it; None: no failure.
    """
    try:
        cell: Cell | None = parse_cell(api.read_cell(job.cell_name)) if job.cell_name else None
    except NotFound:
        cell = None
    except TransientError as error:
        count_failure(error, outcome)
        return None
    return next((a for a in plan_active_job(job, cell, now, timing) if isinstance(a, FinishJob)), None)


def _claim(
    cell: Cell, job: Job, now: datetime, heartbeat_timeout: timedelta, api: Api, outcome: Outcome
) -> dict[str, Any] | None:
    """Claim the cell; on a conflict, re-read it once and retry if it is still free.

    Agents heartbeat into the Cell's status, so a claim often loses only to a
    newer ``lastHeartbeatTime``. The retry decides again on the fresh object and
    carries its resourceVersion: a claim by anyone else shows in ``currentJob``
    (claims come first), so this never takes a cell someone else holds.
    """
    try:
        return api.patch(patches.claim_cell(cell, job, now))
    except Conflict as error:
        count_failure(error, outcome)
    except TransientError as error:
        count_failure(error, outcome)
        return None
    try:
        fresh = parse_cell(api.read_cell(cell.name))
    except TransientError as error:
        count_failure(error, outcome)
        return None
    fresh = replace(fresh, invalid=check_cell(fresh))
    same_pool = (fresh.embodiment, fresh.task, fresh.preflight) == (cell.embodiment, cell.task, cell.preflight)
    free = derive_cell_phase(fresh, False, now, heartbeat_timeout) is CellPhase.READY
    if fresh.current_job is not None or not same_pool or not free:
        return None
    try:
        return api.patch(patches.claim_cell(fresh, job, now))
    except TransientError as error:
        count_failure(error, outcome)
        return None


def _bind(binding: Binding, now: datetime, heartbeat_timeout: timedelta, api: Api) -> Outcome:
    """Claim the cell, then bind the job; give the cell back if the job moved meanwhile.

    Two writes, so submit->bound is short; the caller adds a new job's finalizer
    afterwards. A job deleted before that finalizer vanishes at once: its bind
    fails (the claim is given back here) or, once bound, its cell names a job that
    no longer exists and the repair releases it after the claim grace.
    """
    outcome = Outcome()
    job, cell = binding.job, binding.cell
    claimed = _claim(cell, job, now, heartbeat_timeout, api, outcome)
    if claimed is None:
        return outcome
    outcome.cells_written[cell.name] = parse_cell(claimed)
    try:
        bound = parse_job(api.patch(patches.bind_job(job, cell, now)))
    except TransientError as error:
        count_failure(error, outcome)
        # The job changed (cancelled, deleted, bound elsewhere): give the cell back now
        # rather than waiting for the claim grace. If this fails too, the repair does it.
        rv = str(claimed.get("metadata", {}).get("resourceVersion", ""))
        free = Cell(**{**cell.__dict__, "resource_version": rv})
        phase = derive_cell_phase(free, False, now, timedelta.max)
        released = write(api, patches.release_cell(free, phase), outcome)
        if released is not None:
            outcome.cells_written[cell.name] = parse_cell(released)
        return outcome
    outcome.jobs_written[job.key] = bound
    outcome.writes += 2
    outcome.bound.append((job, cell))
    post_event(api, job, "Normal", "Bound", f"bound to cell {cell.name}")
    return outcome


def _queue_writes_due(
    queued: Mapping[str, QueueEntry],
    jobs: Mapping[str, Job],
    now: datetime,
    memory: Memory,
    limits: Limits,
) -> list[tuple[str, QueueEntry]]:
    due = [
        (key, entry)
        for key, entry in queued.items()
        if _queue_write_due(jobs[key], entry, memory.queue_written_at.get(key), now, limits)
    ]
    return due[: limits.max_queue_writes]


def _queue(job: Job, finalize: bool, entry: QueueEntry | None, now: datetime, api: Api) -> Outcome:
    """The finalizer (if due), then the queue status (if due), each on the latest version."""
    outcome = Outcome()
    if finalize:
        written = _add_finalizer(job, api, outcome)
        if written is None:
            return outcome
        job = outcome.jobs_written[job.key] = parse_job(written)
    if entry is not None:
        written = write(api, patches.queue_job(job, entry, now), outcome)
        if written is not None:
            outcome.jobs_written[job.key] = parse_job(written)
    return outcome


def _add_finalizer(job: Job, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """Append the finalizer; return the job as written only if it is still the job we decided on.

    Callers chain their next write (queue status, requeue, cancel) on the returned
    version, and stop on None. A job that changed meanwhile still gets its
    finalizer (recorded in ``outcome``), but the chain stops: see ``decided_on_same_job``.
    """
    written = _append_finalizer(job, api, outcome)
    if written is None:
        return None
    fresh = parse_job(written)
    if not decided_on_same_job(job, fresh):
        outcome.jobs_written[job.key] = fresh
        return None
    return written


def _append_finalizer(job: Job, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """Append the finalizer (no resourceVersion); if the list changed shape, re-read once.

    The JSON Patch fails only when the finalizer list appeared or vanished since
    the snapshot. The retry decides again on the fresh object: nothing to do if
    the job already has the finalizer, is terminal (it is being released; the
    finalizer would only delay its deletion) or is being deleted.
    """
    try:
        written = api.patch(patches.add_finalizer(job))
    except Conflict as error:
        count_failure(error, outcome)
    except TransientError as error:
        count_failure(error, outcome)
        return None
    else:
        outcome.writes += 1
        return written
    try:
        fresh = parse_job(api.read_job(job.namespace, job.name))
    except TransientError as error:
        count_failure(error, outcome)
        return None
    if fresh.has_finalizer or fresh.terminal or fresh.deleting:
        return None
    return write(api, patches.add_finalizer(fresh), outcome)


def _queue_write_due(
    job: Job, entry: QueueEntry, last: datetime | None, now: datetime, limits: Limits
) -> bool:
    """Phase and reason changes go out at once; position and estimate changes are rate limited.

    An estimate counts as changed when it moved by ``ESTIMATE_STEP`` or more, or
    appeared or vanished: an overdue job ahead moves every estimate behind it a
    little each pass.
    """
    if job.phase is not JobPhase.QUEUED or job.queued_reason != entry.reason:
        return True
    if job.queue_position == entry.position and not _estimate_moved(job.estimated_start, entry.latest_start) \
            and not _estimate_moved(job.likely_start, entry.likely_start):
        return False
    return last is None or now - last >= limits.position_refresh


#: How far ``status.estimatedStart`` or ``likelyStart`` may drift from the plan before it is written again.
ESTIMATE_STEP = timedelta(seconds=60)


def _estimate_moved(written: datetime | None, planned: datetime | None) -> bool:
    if written is None or planned is None:
        return written is not planned
    return abs(planned - written) >= ESTIMATE_STEP


__all__ = ["Api", "Failure", "Limits", "Memory", "Outcome", "reconcile_once", "screen"]
