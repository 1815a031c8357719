"""Lifecycle decisions: repair, offline handling, cancellation, finalizers, TTL.

Pure and level-based: given the whole snapshot and ``now`` it says what must
change, whatever happened before (a crash between two writes, a lost watch
event, a second replica). Applying an action twice is harmless because the
edge writes every change with a resourceVersion precondition.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from datetime import datetime, timedelta

from .artifact_removal import upload_pending
from .duty_cycle import DutyState, next_state
from .health import derive_cell_phase, heartbeat_fresh, heartbeat_lost_for
from .model import Cell, CellPhase, Job, JobPhase, PreflightPhase, Timing
from .preflight import needs_cancel, needs_start
from .scheduling import occupied_cells

MAX_TTL_SECONDS = 366 * 24 * 3600
"""The CRD's maximum for ``ttlSecondsAfterFinished``; older or hand-made objects are clamped to it."""


@dataclass(frozen=True)
class ReleaseCell:
    """Free the cell. ``recheck`` is set when the decision rests on this replica's view
    of the claiming job (unbound, or missing), which a lagging watch can make stale:
    the writer then reads the job from the server and asks ``release_reason`` again.
    """

    cell: Cell
    phase: CellPhase
    reason: str
    recheck: bool = False
    duty: DutyState | None = None
    """The duty cycle's state to record with it (``duty_cycle``); None: unchanged."""


@dataclass(frozen=True)
class SetCellPhase:
    cell: Cell
    phase: CellPhase
    duty: DutyState | None = None
    """The duty cycle's state to record with it (``duty_cycle``); None: unchanged."""


@dataclass(frozen=True)
class RequeueJob:
    job: Job
    message: str


@dataclass(frozen=True)
class FinishJob:
    """End the job. ``recheck_cell`` is set when the verdict rests on this replica's view of
    the job's cell (its claim, its heartbeat, its existence), which a lagging watch can make
    stale: the writer then reads the cell from the server and asks ``plan_active_job`` again.
    """

    job: Job
    phase: JobPhase
    reason: str
    error: str | None = None
    recheck_cell: bool = False


@dataclass(frozen=True)
class RepairStatus:
    """Clear status fields that could not be read (named in ``job.status_defects``)."""

    job: Job


@dataclass(frozen=True)
class RequestCancel:
    job: Job


@dataclass(frozen=True)
class RequeuePreempted:
    """Create the copy that runs a preempted job again (``requeue``), then name it in the job's status."""

    job: Job


@dataclass(frozen=True)
class StartPreflight:
    """Create the job's pre-flight (``preflight``; or find the one made before a crash), then name it in
    ``status.preflight``."""

    job: Job


@dataclass(frozen=True)
class ConcludePreflight:
    """Give the verdict on the job's finished pre-flight. ``preflight`` is it as this replica sees it; None
    when its watch does not show it (just created, or gone): the writer reads it from the server."""

    job: Job
    preflight: Job | None


@dataclass(frozen=True)
class CancelPreflight:
    """Cancel a pre-flight (``job``) whose own job is gone, cancelled or over: it must not hold a twin for nothing.

    ``recheck`` is set when the decision rests on the job not being in this replica's view
    (a watch still listing, or lagging): the writer then reads it from the server first.
    """

    job: Job
    recheck: bool = False


@dataclass(frozen=True)
class AddFinalizer:
    job: Job


@dataclass(frozen=True)
class RemoveFinalizer:
    job: Job


@dataclass(frozen=True)
class DeleteJob:
    job: Job


Action = (
    ReleaseCell
    | SetCellPhase
    | RequeueJob
    | FinishJob
    | RequestCancel
    | RequeuePreempted
    | StartPreflight
    | ConcludePreflight
    | CancelPreflight
    | RepairStatus
    | AddFinalizer
    | RemoveFinalizer
    | DeleteJob
)


def plan_lifecycle(
    jobs: Iterable[Job], cells: Iterable[Cell], now: datetime, timing: Timing
) -> tuple[Action, ...]:
    jobs = list(jobs)
    cells = list(cells)
    by_key = {job.key: job for job in jobs}
    by_name = {cell.name: cell for cell in cells}
    claimed = {cell.current_job for cell in cells if cell.current_job}
    by_uid = {job.uid: job for job in jobs if job.uid}
    actions: list[Action] = []
    actions.extend(_plan_cells(cells, jobs, by_key, now, timing))
    for job in jobs:
        actions.extend(_plan_job(job, by_name, job.key in claimed, now, timing))
        actions.extend(_plan_preflight(job, by_key, by_uid))
    return tuple(actions)


def _plan_preflight(job: Job, by_key: dict[str, Job], by_uid: dict[str, Job]) -> list[Action]:
    """A job's pre-flight: start it, give its verdict once it ends; stop a pre-flight whose job is gone or done.

    Level-based like the rest: a job waiting with ``spec.preflight`` and no
    ``status.preflight`` gets one; a ``Running`` one whose pre-flight is terminal (or not in
    view) gets its verdict. A job being cancelled or deleted is cancelled as any queued job
    (``_plan_cancel``); its pre-flight is then cancelled from here, as the pre-flight of a
    job that is over.
    """
    if job.is_preflight:
        owner = by_uid.get(job.preflight_for or "")
        return [CancelPreflight(job, recheck=owner is None)] if needs_cancel(job, owner) else []
    if needs_start(job):
        return [StartPreflight(job)]
    if job.preflight_phase is PreflightPhase.RUNNING and job.preflight_job and job.waiting:
        found = by_key.get(f"{job.namespace}/{job.preflight_job}")
        preflight = found if found is not None and found.preflight_for == job.uid else None
        if preflight is None or preflight.terminal:
            return [ConcludePreflight(job, preflight)]
    return []


def _plan_cells(
    cells: list[Cell], jobs: list[Job], by_key: dict[str, Job], now: datetime, timing: Timing
) -> list[Action]:
    occupied = occupied_cells(jobs, cells)
    actions: list[Action] = []
    for cell in cells:
        job = by_key.get(cell.current_job or "")
        release = release_reason(cell, job, now, timing)
        if release is not None:
            duty = _duty_change(cell, False, now)
            free = cell if duty is None else replace(cell, duty=duty)
            free_phase = derive_cell_phase(free, False, now, timing.heartbeat_timeout)
            finished = job is not None and job.terminal and job.cell_name == cell.name
            actions.append(ReleaseCell(cell, free_phase, release, recheck=not finished, duty=duty))
            continue
        busy = cell.name in occupied
        duty = _duty_change(cell, busy, now)
        phase = derive_cell_phase(cell if duty is None else replace(cell, duty=duty), busy, now,
                                  timing.heartbeat_timeout)
        if phase != cell.phase or cell.invalid != cell.message or duty is not None:
            actions.append(SetCellPhase(cell, phase, duty))
    return actions


def _duty_change(cell: Cell, occupied: bool, now: datetime) -> DutyState | None:
    """The duty cycle's next state when it differs from the recorded one (``duty_cycle.next_state``)."""
    planned = next_state(cell.duty_cycle, cell.duty, occupied, now)
    return None if planned == cell.duty else planned


def release_reason(cell: Cell, job: Job | None, now: datetime, timing: Timing) -> str | None:
    """Why the cell's claim must go, or None if it stands (or there is none).

    ``job`` is the job the claim names, as far as the caller knows (None: gone).
    """
    if not cell.current_job:
        return None
    if job is not None and job.active and job.cell_name == cell.name:
        return None
    if job is not None and job.terminal and job.cell_name == cell.name:
        return f"job {job.key} finished ({job.phase})"
    # Claimed but not bound: either the binder is between its two writes (wait)
    # or it crashed there (repair). The grace tells the two apart.
    if cell.claimed_at is not None and now - cell.claimed_at < timing.claim_grace:
        return None
    if job is None:
        return f"job {cell.current_job} no longer exists"
    return f"claim for job {job.key} was never completed"


def _plan_job(
    job: Job, cells: dict[str, Cell], claimed: bool, now: datetime, timing: Timing
) -> list[Action]:
    actions: list[Action] = []
    if job.status_defects:
        actions.append(RepairStatus(job))
    # Only on a job that holds a cell (bound, or named by a cell's claim): the finalizer
    # protects the cell's release, and a waiting or finished job holds none (a cell still
    # naming one is released by ``_plan_cells`` either way). Written for every new job, it
    # doubled the writes of a burst of submissions, and every delete of a queued job
    # waited for the operator.
    if not job.deleting and not job.terminal and not job.has_finalizer and (job.active or claimed):
        actions.append(AddFinalizer(job))
    if job.terminal:
        # A finished job has nothing left for the finalizer to protect once its cell is
        # released, deleted or not: left on, it would hang every later delete of the job
        # (and of the CRD) whenever no operator runs, e.g. after ``helm uninstall``.
        if job.has_finalizer and not claimed:
            actions.append(RemoveFinalizer(job))
        if requeue_due(job):
            # Before any TTL: the copy is created from this job, which must exist until then.
            actions.append(RequeuePreempted(job))
            return actions
        # At its TTL; with the operator removing stored outputs with the job
        # (``artifact_removal``), once the node agent's upload has settled (bounded), so
        # nothing is stored after the removal.
        ttl_end = _ttl_end(job, timing)
        if not job.deleting and ttl_end is not None and now >= ttl_end \
                and not (timing.outputs_store and upload_pending(job, now, ttl_end)):
            actions.append(DeleteJob(job))
        return actions
    cell = cells.get(job.cell_name or "")
    if job.cancel or job.deleting:
        actions.extend(_plan_cancel(job, cell, now, timing))
    elif job.active:
        actions.extend(plan_active_job(job, cell, now, timing))
    elif job.spec_problem is not None:
        actions.append(FinishJob(job, JobPhase.FAILED, "InvalidSpec", job.spec_problem))
    return actions


def requeue_due(job: Job) -> bool:
    """A preempted job whose spec asks for a requeue and that has none yet (cancelled or deleted: none)."""
    return (job.phase is JobPhase.PREEMPTED and job.requeue_on_preemption and job.requeued_as is None
            and not job.cancel and not job.deleting)


def _plan_cancel(job: Job, cell: Cell | None, now: datetime, timing: Timing) -> list[Action]:
    if not job.active:
        # Said in the result: the customer following the job sees why it ended.
        error = "the job was cancelled before it started" if job.cancel else "the job was deleted before it started"
        return [FinishJob(job, JobPhase.CANCELLED, "Cancelled", error)]
    if job.cancel_requested_at is None:
        return [RequestCancel(job)]
    agent_gone = cell is None or not heartbeat_fresh(cell, now, timing.heartbeat_timeout)
    if agent_gone and now - job.cancel_requested_at >= timing.cancel_force_after:
        error = (
            f"cancelled without confirmation: the agent of cell {job.cell_name} did not "
            f"report within {int(timing.cancel_force_after.total_seconds())}s"
        )
        return [FinishJob(job, JobPhase.CANCELLED, "CancelForced", error)]
    return []


def plan_active_job(job: Job, cell: Cell | None, now: datetime, timing: Timing) -> list[Action]:
    """What a dispatched or running job needs, given its cell as far as the caller knows (None: gone)."""
    name = job.cell_name
    if cell is None:
        if job.phase is JobPhase.DISPATCHED:
            return [RequeueJob(job, f"cell {name} was deleted before the job started")]
        return [FinishJob(job, JobPhase.FAILED, "CellLost", f"cell {name} lost (deleted)", recheck_cell=True)]
    bound_for = now - job.bound_at if job.bound_at else timedelta.max
    if job.phase is JobPhase.DISPATCHED:
        if cell.current_job != job.key and bound_for >= timing.claim_grace:
            return [RequeueJob(job, f"cell {name} does not hold this job's claim")]
        if not heartbeat_fresh(cell, now, timing.heartbeat_timeout):
            return [RequeueJob(job, f"cell {name} went offline before the job started")]
        return []
    if cell.current_job != job.key and bound_for >= timing.claim_grace:
        # The cell's claim is the one truth: a job that says it runs on a cell
        # that does not hold it (a hand-written status, a second "running" job)
        # cannot be trusted with the arm; the agent never started it there.
        holder = cell.current_job or "no job"
        return [FinishJob(job, JobPhase.FAILED, "ClaimNotHeld",
                          f"cell {name} does not hold this job's claim (it holds {holder}); "
                          "a job runs only on the cell that claims it", recheck_cell=True)]
    if heartbeat_lost_for(cell, now, timing.heartbeat_timeout) >= timing.lost_grace:
        return [FinishJob(job, JobPhase.FAILED, "CellLost", f"cell {name} lost", recheck_cell=True)]
    return []


def _ttl_end(job: Job, timing: Timing) -> datetime | None:
    """When the finished job is due for deletion; None: never (no TTL, or not finished)."""
    if job.finished_at is None:
        return None
    if job.ttl_seconds_after_finished is not None:
        # Clamped: timedelta overflows near 10**14 s, and no TTL needs more than a year.
        ttl = timedelta(seconds=min(max(job.ttl_seconds_after_finished, 0), MAX_TTL_SECONDS))
    elif timing.default_ttl is not None:
        ttl = timing.default_ttl
    else:
        return None
    return job.finished_at + ttl
