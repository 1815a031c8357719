"""What one reconcile pass writes through: the ``Api`` it talks to, the ``Outcome`` it records, and
the write, failure and Event helpers every writer of the pass shares (``reconcile``, ``derived_jobs``).

No I/O of its own: the ``Api`` is the operator's real API server client or the property test's
in-memory world with the same optimistic-concurrency rules.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Protocol

from . import patches
from .errors import Conflict, NotFound, TransientError
from .model import Cell, Job
from .quota import QuotaObject
from .scheduling import QueueEntry

log = logging.getLogger(__name__)


class Api(Protocol):
    def patch(self, patch: patches.Patch) -> dict[str, Any]:
        """Apply the patch; raise Conflict on a failed precondition, NotFound if gone."""

    def delete_job(self, namespace: str, name: str, uid: str) -> None: ...

    def read_cell(self, name: str) -> dict[str, Any]:
        """The Cell as the server has it now; raise NotFound if gone."""

    def read_job(self, namespace: str, name: str) -> dict[str, Any]:
        """The RobotJob as the server has it now; raise NotFound if gone."""

    def create_job(self, body: dict[str, Any]) -> dict[str, Any]:
        """Create the RobotJob; raise AlreadyExists if its name is taken."""

    def post_event(self, subject: Job | Cell | QuotaObject, type_: str, reason: str, message: str) -> None: ...

    @property
    def outputs_bucket(self) -> str | None:
        """The object store's bucket of job outputs (docs/outputs.md); None: the operator has no store."""

    def remove_outputs(self, prefix: str) -> int:
        """Remove every object under ``prefix`` in that bucket; how many. Raise StoreError when the store fails."""


@dataclass(frozen=True)
class Failure:
    """One object a pass could not handle: it was skipped, the rest were scheduled."""

    subject: Job | Cell
    error: str

    @property
    def kind(self) -> str:
        return "RobotJob" if isinstance(self.subject, Job) else "Cell"

    @property
    def name(self) -> str:
        return self.subject.key if isinstance(self.subject, Job) else self.subject.name


@dataclass
class Outcome:
    bound: list[tuple[Job, Cell]] = field(default_factory=list)
    conflicts: int = 0
    requeued: int = 0
    errors: int = 0
    writes: int = 0
    queue: dict[str, QueueEntry] = field(default_factory=dict)
    jobs_written: dict[str, Job] = field(default_factory=dict)
    cells_written: dict[str, Cell] = field(default_factory=dict)
    deleted: set[str] = field(default_factory=set)
    failed: dict[str, Failure] = field(default_factory=dict)
    more: bool = False
    """Queue writes were left for the next pass (``Limits.max_queue_tasks``): run it soon."""
    quotas_ignored: int = 0
    """CellQuotas in scope that this pass did not apply (malformed, or duplicating another's scope)."""
    preempted: dict[str, int] = field(default_factory=dict)
    """Running jobs asked to stop at their next episode boundary, by why (``Reclaim.reason``)."""
    requeued_copies: int = 0
    """Preempted jobs whose copy now waits in the queue in their place (``requeue``)."""
    preflights: dict[str, int] = field(default_factory=dict)
    """Pre-flights given their verdict, by verdict (``passed``, ``failed``)."""
    outputs_removed: dict[str, int] = field(default_factory=dict)
    """Finished jobs' stored outputs removed with the job at its TTL, by outcome (``removed``, ``failed``)."""

    def merge(self, other: Outcome) -> None:
        self.bound.extend(other.bound)
        self.failed.update(other.failed)
        self.jobs_written.update(other.jobs_written)
        self.cells_written.update(other.cells_written)
        self.deleted.update(other.deleted)
        self.conflicts += other.conflicts
        self.requeued += other.requeued
        for reason, count in other.preempted.items():
            self.preempted[reason] = self.preempted.get(reason, 0) + count
        self.requeued_copies += other.requeued_copies
        for verdict, count in other.preflights.items():
            self.preflights[verdict] = self.preflights.get(verdict, 0) + count
        for result, count in other.outputs_removed.items():
            self.outputs_removed[result] = self.outputs_removed.get(result, 0) + count
        self.errors += other.errors
        self.writes += other.writes


def write(api: Api, patch: patches.Patch, outcome: Outcome) -> dict[str, Any] | None:
    """Apply ``patch``; None when it failed (counted in ``outcome``: the next pass tries again)."""
    try:
        written = api.patch(patch)
    except TransientError as error:
        count_failure(error, outcome)
        return None
    outcome.writes += 1
    return written


def count_failure(error: TransientError, outcome: Outcome) -> None:
    """A failed write: a conflict or a vanished object is expected on a snapshot; anything else is logged."""
    if isinstance(error, Conflict):
        outcome.conflicts += 1
    elif not isinstance(error, NotFound):
        outcome.errors += 1
        log.warning("write failed, retrying next pass: %s", error)


def post_event(api: Api, subject: Job | Cell | QuotaObject, type_: str, reason: str, message: str) -> None:
    """Best effort: an Event that cannot be posted never fails the write it tells of."""
    try:
        api.post_event(subject, type_, reason, message)
    except Exception as error:  # noqa: BLE001 - events are best effort by design
        log.debug("event not posted for %s: %s", subject, error)


__all__ = ["Api", "Failure", "Outcome", "count_failure", "post_event", "write"]
