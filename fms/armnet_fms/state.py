"""The FMS's latest view of the fleet: cells and their jobs (polled) and pending resets (heard on NATS).

One writer per field: the poller replaces ``cells``/``jobs``; the NATS callback
and the confirm action change ``pending``. Both run on the web server's event
loop, so no lock is needed.

The agent repeats a reset's notice while the reset waits (a core NATS notice
can be lost), so a notice for the reset already shown changes nothing (its
deadline stays the one first reckoned); a notice for a wait that began before
the one shown never replaces it (a late repeat), nor does one naming a job the
cell does not run (a stale or forged notice) replace the running job's; one for a reset past its
deadline here never brings its button back, and one for a reset confirmed or
replaced here does not for ``REPEAT_GRACE_S`` (a repeat already in flight),
after which the button comes back: the job still waits, so the confirmation
was lost.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from .actions import AuditEvent
from .view import (
    CellRow,
    PendingReset,
    build_fleet,
    current_job_uid,
    jobs_by_key,
    pending_from_notice,
)

log = logging.getLogger(__name__)

#: How many ended reset requests are remembered (a repeat of one still in flight must not revive it).
ENDED_REQUESTS_KEPT = 1024
#: How long repeats of a request confirmed or replaced here are ignored: five of the agent's repeat periods.
REPEAT_GRACE_S = 10.0


class FleetSource(Protocol):
    """Where cells and jobs come from and where actions go: the API server (``kube``) or a local run (``local``)."""

    def list_cells(self) -> list[dict[str, Any]]: ...
    def current_jobs(self, cells: list[dict[str, Any]]) -> list[dict[str, Any]]: ...
    def get_cell(self, name: str) -> dict[str, Any] | None: ...
    def get_job(self, key: str) -> dict[str, Any] | None: ...
    def patch_cell(self, name: str, patch: dict[str, Any]) -> None: ...
    def patch_job(self, namespace: str, name: str, patch: dict[str, Any]) -> None: ...
    def post_event(self, event: AuditEvent) -> None: ...


@dataclass
class FleetState:
    kube: FleetSource
    poll_s: float = 1.0
    clock: Callable[[], float] = time.time
    cells: list[dict[str, Any]] = field(default_factory=list)
    jobs: list[dict[str, Any]] = field(default_factory=list)
    pending: dict[str, PendingReset] = field(default_factory=dict)
    #: Reset requests that ended here -> until when their notices are ignored (inf: for good), oldest
    #: first, at most ENDED_REQUESTS_KEPT.
    ended_requests: dict[str, float] = field(default_factory=dict)
    kube_ok: bool = False
    kube_errors: int = 0
    changed: asyncio.Event = field(default_factory=asyncio.Event)
    _refreshing: asyncio.Task[None] | None = field(default=None, repr=False)

    def refresh_soon(self) -> None:
        """Re-read the fleet in the background, one re-read at a time.

        An action's answer does not wait for it: on a busy host the answer to a tap
        waited behind a full list of cells and jobs, and the page keeps the verdict
        buttons disabled until the answer comes. The page learns the new state from
        the live stream when the re-read lands (or from the next poll).
        """
        if self._refreshing is None or self._refreshing.done():
            self._refreshing = asyncio.get_running_loop().create_task(self.refresh())

    async def refresh(self) -> None:
        try:
            cells = await asyncio.to_thread(self.kube.list_cells)
            jobs = await asyncio.to_thread(self.kube.current_jobs, cells)
        except Exception as error:  # noqa: BLE001 - keep serving the last view; the page shows it is stale
            self.kube_ok = False
            self.kube_errors += 1
            log.warning("cannot read cells from the Kubernetes API: %s", str(error)[:200])
            return
        self.cells, self.jobs, self.kube_ok = cells, jobs, True
        self._forget_expired()
        self.changed.set()

    async def poll_forever(self) -> None:
        while True:
            await self.refresh()
            await asyncio.sleep(self.poll_s)

    def on_reset_requested(self, cell: str, notice: dict[str, Any]) -> None:
        spec = next(((c.get("spec") or {}) for c in self.cells
                     if (c.get("metadata") or {}).get("name") == cell), None)
        if spec is None:
            return  # not a cell we know; a forged notice must not create a button
        now = self.clock()
        pending = pending_from_notice(cell, notice, float(spec.get("resetTimeoutSeconds") or 300), now)
        if pending is None or now < self.ended_requests.get(pending.request_id, -math.inf):
            return
        shown = self.pending.get(cell)
        if shown is not None:
            if shown.request_id == pending.request_id or pending.began_at <= shown.began_at:
                return  # a repeat of the reset shown, or of an earlier wait arriving late
            running = self._current_job_uid(cell)
            if shown.job_uid == running != pending.job_uid:
                return  # a notice naming a job the cell does not run never hides the real prompt
            self._ended(shown.request_id, now + REPEAT_GRACE_S)  # a later wait replaces it
        self.pending[cell] = pending
        self.changed.set()

    def clear_reset(self, cell: str, request_id: str) -> None:
        if cell in self.pending and self.pending[cell].request_id == request_id:
            self._ended(request_id, self.clock() + REPEAT_GRACE_S)
            del self.pending[cell]
            self.changed.set()

    def _current_job_uid(self, cell: str) -> str | None:
        """The uid of the job the cell ran at the last poll (``status.currentJob``), if any."""
        listed = next((c for c in self.cells if (c.get("metadata") or {}).get("name") == cell), None)
        return current_job_uid(listed, jobs_by_key(self.jobs)) if listed is not None else None

    def cell_names(self) -> set[str]:
        """The names of the Cells read last (the only cells whose telemetry the FMS keeps)."""
        return {str(name) for c in self.cells if (name := (c.get("metadata") or {}).get("name"))}

    def rows(self, *, site: str = "", query: str = "") -> list[CellRow]:
        return build_fleet(self.cells, self.jobs, self.pending, self.clock(), site=site, query=query)

    def _forget_expired(self) -> None:
        now = self.clock()
        for cell in [c for c, p in self.pending.items() if p.expired(now)]:
            self._ended(self.pending.pop(cell).request_id, math.inf)  # the job's wait is over too

    def _ended(self, request_id: str, ignored_until: float) -> None:
        self.ended_requests.pop(request_id, None)  # re-added last: the newest stay longest
        self.ended_requests[request_id] = ignored_until
        while len(self.ended_requests) > ENDED_REQUESTS_KEPT:
            del self.ended_requests[next(iter(self.ended_requests))]
