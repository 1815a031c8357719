"""The RobotJobs a reconcile pass makes from others, and what comes before and after them.

A preemption's request on the job that gives its cell back; a preempted job's copy,
created once and named in its status (``requeue``); a job's pre-flight, created once,
then its verdict written on the job (``preflight``); and the fresh read that tells
whether a pre-flight's job is gone. Each creation copies the job as the server has
it now and only when the decision, taken on a snapshot that may lag, still holds.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from datetime import datetime
from typing import Any

from . import patches
from .errors import AlreadyExists, NotFound, TransientError
from .fairshare import Reclaim
from .lifecycle import requeue_due
from .model import Job, Timing
from .parsing import parse_job
from .pass_io import Api, Outcome, count_failure, post_event, write
from .preflight import (
    PREFLIGHT_FAILED,
    device_calls_of,
    failed_error,
    is_preflight_of,
    judge,
    needs_cancel,
    needs_start,
    preflight_body,
    preflight_name,
    started_status,
    verdict_status,
)
from .requeue import is_requeue_of, requeue_body, requeue_name

log = logging.getLogger(__name__)


def preempt(reclaim: Reclaim, now: datetime, timing: Timing, api: Api) -> Outcome:
    """Ask the agent to stop the borrowing job at its next episode boundary; an Event on both jobs."""
    outcome = Outcome()
    victim, owner = reclaim.job, reclaim.for_job
    request = patches.request_preemption(victim, owner.key, reclaim.message, timing.episode_wait, now)
    written = write(api, request, outcome)
    if written is None:
        return outcome
    outcome.jobs_written[victim.key] = parse_job(written)
    outcome.preempted[reclaim.reason] = outcome.preempted.get(reclaim.reason, 0) + 1
    wait = int(timing.episode_wait.total_seconds())
    log.info("preempting %s on cell %s for %s: %s", victim.key, reclaim.cell, owner.key, reclaim.message)
    post_event(api, victim, "Warning", "Preempted",
           f"{reclaim.message}: the job stops at its next episode boundary (its grace window opens then, "
           f"or in {wait} s without one)")
    post_event(api, owner, "Normal", "Preempting",
           f"job {victim.key} on cell {reclaim.cell} stops at its next episode boundary for this job")
    return outcome


def _still_due(
    job: Job, api: Api, outcome: Outcome, due: Callable[[Job], bool],
) -> tuple[dict[str, Any], Job] | None:
    """The job as the server has it now, body and model, if it is the same job and ``due`` still holds.

    A job made from another (its requeue, its pre-flight) is copied from the body the server
    returns (the snapshot's frozen ``Job`` has no args, secrets or labels), and only when the
    decision, taken on a snapshot that may lag, holds on that fresh read.
    """
    try:
        current = api.read_job(job.namespace, job.name)
    except TransientError as error:
        count_failure(error, outcome)
        return None
    fresh = parse_job(current)
    if fresh.uid != job.uid or not due(fresh):
        return None
    return current, fresh


def _made_from(
    job: Job, api: Api, outcome: Outcome, due: Callable[[Job], bool],
    create: Callable[[dict[str, Any], Job, Api, Outcome], dict[str, Any] | None],
) -> tuple[Job, dict[str, Any]] | None:
    """The job as the server has it now and the job ``create`` made from it (now, or before a crash).

    None when ``due`` no longer holds on the fresh read or a write failed: the next pass decides again.
    """
    read = _still_due(job, api, outcome, due)
    if read is None:
        return None
    current, fresh = read
    made = create(current, fresh, api, outcome)
    return None if made is None else (fresh, made)


def requeue_preempted(job: Job, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """Create the preempted job's copy (or find the one made before a crash), then name it in its status."""
    made = _made_from(job, api, outcome, requeue_due, _create_requeue)
    if made is None:
        return None
    fresh, copy = made
    name = str(copy["metadata"]["name"])
    written = write(api, patches.name_requeue(fresh, name), outcome)
    if written is not None:
        outcome.requeued_copies += 1
        post_event(api, fresh, "Normal", "Requeued", f"preempted; {name} runs it again, in its place in the queue")
        post_event(api, parse_job(copy), "Normal", "RequeuedFrom",
               f"runs preempted job {job.name} again, in its place in the queue")
    return written


def _create_requeue(current: dict[str, Any], job: Job, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """The copy as created now, or as found (created for this job before); None to retry next pass."""
    return _create_once(job, api, outcome, lambda taken: requeue_name(job.name, job.uid, taken),
                        lambda name: requeue_body(current, name, job.created), is_requeue_of)


def _create_once(
    job: Job, api: Api, outcome: Outcome, name_for: Callable[[bool], str],
    body_for: Callable[[str], dict[str, Any]], made_for: Callable[[Mapping[str, Any], str], bool],
) -> dict[str, Any] | None:
    """Create a RobotJob made from ``job`` (its requeue, its pre-flight) once, even across a crash.

    ``name_for(taken_by_other)`` names it; when a job of that name exists, it is the one
    made for ``job`` before (``made_for(existing, job.uid)``: its annotation names the uid)
    and is returned as found, or a tenant's own job, and the uid-suffixed name is tried.
    None: a write failed, the next pass tries again.
    """
    for taken_by_other in (False, True):
        name = name_for(taken_by_other)
        try:
            made = api.create_job(body_for(name))
        except AlreadyExists:
            try:
                existing = api.read_job(job.namespace, name)
            except TransientError as error:
                count_failure(error, outcome)
                return None
            if made_for(existing, job.uid):
                return existing
            continue
        except TransientError as error:
            count_failure(error, outcome)
            return None
        outcome.writes += 1
        return made
    return None


def start_preflight(job: Job, now: datetime, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """Create the job's pre-flight (or find the one made before a crash), then name it in ``status.preflight``.

    The body is copied from the job as the server has it now (the snapshot's frozen ``Job``
    has no args, secrets or labels), as a preempted job's requeue is.
    """
    both = _made_from(job, api, outcome, needs_start, _create_preflight)
    if both is None:
        return None
    fresh, made = both
    name = str(made["metadata"]["name"])
    written = write(api, patches.start_preflight(fresh, started_status(name, now)), outcome)
    if written is not None:
        # Scheduled in this same pass: a free twin takes it at once.
        outcome.jobs_written[f"{job.namespace}/{name}"] = parse_job(made)
        post_event(api, fresh, "Normal", "PreflightStarted",
               f"pre-flight job {name} runs this job on a simulated twin first (at most "
               f"{fresh.preflight_seconds} s); the job joins the queue for a real cell once it passes")
    return written


def _create_preflight(current: dict[str, Any], job: Job, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """The pre-flight as created now, or as found (created for this job before); None to retry next pass."""
    return _create_once(job, api, outcome, lambda taken: preflight_name(job.name, job.uid, taken),
                        lambda name: preflight_body(current, name), is_preflight_of)


def conclude_preflight(job: Job, now: datetime, api: Api, outcome: Outcome) -> dict[str, Any] | None:
    """Read the finished pre-flight's result, write the verdict on the job; a failed one fails the job.

    The pre-flight is read from the server even when the snapshot has it: its error and
    traceback are in ``status.result``, which the frozen ``Job`` does not carry, and a
    pre-flight the watch does not show yet (just created) must not be taken for gone.
    """
    name = job.preflight_job or ""
    try:
        body: dict[str, Any] | None = api.read_job(job.namespace, name)
    except NotFound:
        body = None
    except TransientError as error:
        count_failure(error, outcome)
        return None
    if body is not None and not is_preflight_of(body, job.uid):
        body = None  # a job of that name, but not this job's pre-flight: its own is gone
    result = ((body or {}).get("status") or {}).get("result") or {}
    verdict = judge(parse_job(body) if body is not None else None, name, result.get("error"), result.get("traceback"),
                    device_calls_of(result))
    if verdict is None:
        return None  # still running (the snapshot was behind)
    failure = None if verdict.passed else failed_error(verdict)
    written = write(api, patches.conclude_preflight(job, verdict_status(name, verdict, now), failure, now), outcome)
    if written is None:
        return None
    label = verdict.label
    outcome.preflights[label] = outcome.preflights.get(label, 0) + 1
    log.info("pre-flight of %s %s: %s", job.key, label, verdict.message)
    if verdict.passed:
        post_event(api, job, "Normal", "PreflightPassed", f"{verdict.message}; the job joins the queue for a real cell")
    else:
        post_event(api, job, "Warning", PREFLIGHT_FAILED, f"{verdict.message}; the job never bound a real cell")
    return written


def owner_gone(preflight: Job, api: Api, outcome: Outcome) -> bool:
    """Whether the job a pre-flight is for is gone, cancelled, deleted or over, as the server has it now.

    This replica's watch may not show it yet (still listing after a start): cancelling
    a healthy job's pre-flight on that view would fail the job. The job is found by the
    pre-flight's ownerReference (a pre-flight without one is not the operator's: gone).
    """
    try:
        body = api.read_job(preflight.namespace, preflight.name)
    except NotFound:
        return False  # the pre-flight itself is gone: nothing to cancel
    except TransientError as error:
        count_failure(error, outcome)
        return False
    refs = (body.get("metadata") or {}).get("ownerReferences") or []
    name = next((r.get("name") for r in refs if isinstance(r, dict) and r.get("uid") == preflight.preflight_for), None)
    if not name:
        return True
    try:
        owner = parse_job(api.read_job(preflight.namespace, str(name)))
    except NotFound:
        return True
    except TransientError as error:
        count_failure(error, outcome)
        return False
    return owner.uid != preflight.preflight_for or needs_cancel(preflight, owner)


__all__ = ["conclude_preflight", "owner_gone", "preempt", "requeue_preempted", "start_preflight"]
