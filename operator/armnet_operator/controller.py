"""The running operator: a cache fed by watch events, and the reconcile loop.

Level-based: every pass reads the whole cache and calls the pure core; watch
events only mark the cache dirty so a pass runs soon. One asyncio task owns
the loop, and only while this replica holds the Lease does it write.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from typing import Any

from armnet_core.backoff import BackoffPolicy

from .errors import PermanentError, ResourceMissing, ResourcesReplaced
from .kube import WRITERS, KubeApi
from .metrics import Metrics
from .model import Cell, Job
from .parsing import parse_cell, parse_job
from .quota import QuotaObject
from .quota_parsing import read_quota
from .reconcile import Limits, Memory, reconcile_once
from .settings import OperatorSettings

log = logging.getLogger(__name__)
DEBOUNCE_SECONDS = 0.05
OVERLAY_SECONDS = 10.0
MAX_BACKOFF_SECONDS = 30.0
#: Retrying a pass whose resources (CRDs) are gone: 1, 2, 4 ... s, at most 30 s apart.
RESOURCES_BACKOFF = BackoffPolicy(first_s=1.0, max_s=MAX_BACKOFF_SECONDS)
FAILED_PASS_FIRST_SECONDS = 1.0
"""A pass that failed (the API server away, a bug) is retried after 1 s (the period if shorter),
doubling while passes keep failing, at most one reconcile period apart: an operator that cannot reach
the API server stops logging a traceback every second, and never waits longer than its own cadence."""
QUEUE_SECONDS_PER_PASS = 0.5
"""Queue writes a pass starts within this budget; the rest go next pass, so a burst never holds a bind long."""
STOP_GRACE_SECONDS = 5.0
"""At a stop, the pass in flight gets this long to end; then the operator stops without it (``KubeApi.close``)."""


class Cache:
    """Latest parsed RobotJobs and Cells, by key, plus what we wrote ahead of the watch.

    Our own writes reach the watch a little later; a pass that started in between
    would act on the old resourceVersions and only collect conflicts. So each
    written object is kept as an overlay until the watch delivers that version
    (or a newer one), or for ``OVERLAY_SECONDS`` at most.
    """

    def __init__(self) -> None:
        self.jobs: dict[str, Job] = {}
        self.cells: dict[str, Cell] = {}
        self.quotas: dict[str, QuotaObject] = {}
        self._job_overlay: dict[str, tuple[Job, float]] = {}
        self._cell_overlay: dict[str, tuple[Cell, float]] = {}
        self._lock = threading.Lock()
        self.changed = asyncio.Event()

    def on_job(self, event_type: str | None, body: Mapping[str, Any]) -> None:
        meta = body.get("metadata") or {}
        key = f"{meta.get('namespace')}/{meta.get('name')}"
        job = None if event_type == "DELETED" else parse_job(body)
        with self._lock:
            if job is None:
                self.jobs.pop(key, None)
                self._job_overlay.pop(key, None)
            else:
                self.jobs[key] = job
                _settle(self._job_overlay, key, job.resource_version)
        self.changed.set()

    def on_cell(self, event_type: str | None, body: Mapping[str, Any]) -> None:
        name = str((body.get("metadata") or {}).get("name"))
        cell = None if event_type == "DELETED" else parse_cell(body)
        with self._lock:
            if cell is None:
                self.cells.pop(name, None)
                self._cell_overlay.pop(name, None)
            else:
                self.cells[name] = cell
                _settle(self._cell_overlay, name, cell.resource_version)
        self.changed.set()

    def on_quota(self, event_type: str | None, body: Mapping[str, Any]) -> None:
        """A CellQuota event; a malformed one is kept too (with its problem), so it is reported."""
        quota = read_quota(body)
        with self._lock:
            if event_type == "DELETED":
                self.quotas.pop(quota.name, None)
            elif _newer(quota.resource_version, self.quotas.get(quota.name)):
                self.quotas[quota.name] = quota
        self.changed.set()

    def load_quotas(self, bodies: list[dict[str, Any]]) -> None:
        """The full list (read once per leadership): nothing binds on a cache the quota watch has not filled."""
        for body in bodies:
            self.on_quota("ADDED", body)

    def quota_snapshot(self) -> list[QuotaObject]:
        with self._lock:
            return list(self.quotas.values())

    def remember(self, jobs: Mapping[str, Job], cells: Mapping[str, Cell], deleted: set[str]) -> None:
        stamp = time.monotonic()
        with self._lock:
            for key, job in jobs.items():
                if key in self.jobs and key not in deleted:
                    self._job_overlay[key] = (job, stamp)
            for name, cell in cells.items():
                if name in self.cells:
                    self._cell_overlay[name] = (cell, stamp)

    def snapshot(self) -> tuple[list[Job], list[Cell]]:
        cutoff = time.monotonic() - OVERLAY_SECONDS
        with self._lock:
            jobs = dict(self.jobs)
            cells = dict(self.cells)
            for key, (job, stamp) in list(self._job_overlay.items()):
                if stamp < cutoff or key not in jobs:
                    del self._job_overlay[key]
                else:
                    jobs[key] = job
            for name, (cell, stamp) in list(self._cell_overlay.items()):
                if stamp < cutoff or name not in cells:
                    del self._cell_overlay[name]
                else:
                    cells[name] = cell
        return list(jobs.values()), list(cells.values())


def _newer(version: str, held: QuotaObject | None) -> bool:
    """A listed quota never replaces a newer one the watch already delivered."""
    if held is None:
        return True
    try:
        return int(version) >= int(held.resource_version)
    except ValueError:
        return True


def _settle(overlay: dict[str, Any], key: str, seen_version: str) -> None:
    """Drop the overlay once the watch shows our version or a later one."""
    entry = overlay.get(key)
    if entry is None:
        return
    ours = entry[0].resource_version
    try:
        caught_up = int(seen_version) >= int(ours)
    except ValueError:  # resourceVersions are opaque in general; etcd's are integers
        caught_up = seen_version == ours
    if caught_up:
        del overlay[key]


class Controller:
    def __init__(
        self,
        settings: OperatorSettings,
        api: KubeApi,
        metrics: Metrics,
        clock: Callable[[], datetime] = lambda: datetime.now(UTC),
        on_death: Callable[[BaseException | None], None] | None = None,
        on_resources_back: Callable[[], None] | None = None,
    ) -> None:
        self.settings = settings
        self.api = api
        self.metrics = metrics
        self.clock = clock
        self.cache = Cache()
        self.memory = Memory()
        self.limits = Limits(
            position_refresh=timedelta(seconds=settings.position_refresh), parallel_binds=WRITERS,
            queue_seconds=QUEUE_SECONDS_PER_PASS, quota_refresh=timedelta(seconds=settings.quota_refresh),
        )
        self._quotas_listed = False
        self.leading = False
        self._renewed_at: datetime | None = None
        self._task: asyncio.Task[None] | None = None
        self._pass: asyncio.Future[None] | None = None
        self._stopping = False
        self._more = False
        self.on_death = on_death
        self.on_resources_back = on_resources_back
        self.died: BaseException | None = None
        self.dead = False
        self.restart_requested = False
        """The loop ended to have kopf's watches started afresh (see ``on_resources_back``)."""
        #: A SIGTERM/SIGINT arrived while kopf stopped for that restart: exit instead.
        self.terminated = False
        self._crd_uids: dict[str, str] | None = None
        self._crds_checked_at: datetime | None = None
        self._crds_replaced = False
        self._crd_check_off = False

    def start(self) -> None:
        self.cache.changed = asyncio.Event()  # bind to the running loop
        self._task = asyncio.get_running_loop().create_task(self._run(), name="armnet-reconcile")
        self._task.add_done_callback(self._ended)

    async def stop(self, grace: float = STOP_GRACE_SECONDS) -> None:
        """Start no pass any more, let the one in flight end (``grace`` at most), then end the loop.

        Cancelling the loop's task does not stop the thread a pass runs in: the pass
        went on writing after kopf's cleanup, and its Events were queued after the
        cleanup had returned (for what that did to the exit, see ``KubeApi.close``).
        Waiting here makes the pass the last thing before the caller closes the API.
        """
        self._stopping = True
        running = self._pass
        if running is not None and not running.done():
            await asyncio.wait({running}, timeout=grace)
            if not running.done():
                log.warning("the reconcile pass is still running %.0f s after the stop; stopping without it", grace)
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)

    def _ended(self, task: asyncio.Task[None]) -> None:
        """The loop must never end on its own: if it does, the process must go, not idle as leader.

        A replica whose loop died still renews nothing, but it keeps its watches
        and its process, so nothing restarts it and (until the Lease expires) no
        other replica takes over. ``on_death`` ends the process non-zero.
        """
        if self._stopping or self.restart_requested:
            return
        self.dead = True
        self.died = None if task.cancelled() else task.exception()
        log.critical("the reconcile loop ended unexpectedly (%r); exiting so the operator is restarted",
                     self.died, exc_info=self.died)
        self.metrics.leader.set(0)
        if self.on_death is not None:
            self.on_death(self.died)

    async def _run(self) -> None:
        period = self.settings.reconcile_period
        backoff = RESOURCES_BACKOFF.start()
        failed_passes = BackoffPolicy(first_s=min(FAILED_PASS_FIRST_SECONDS, period), max_s=period).start()
        while True:
            try:
                await asyncio.wait_for(self.cache.changed.wait(), timeout=max(period, backoff.current_s))
                await asyncio.sleep(DEBOUNCE_SECONDS)  # let a burst of events land in one pass
            except TimeoutError:
                pass
            self.cache.changed.clear()
            if self._stopping:  # stop() is waiting for the last pass to end: no new one
                return
            try:
                self._more = False
                # Shielded: a cancelled loop leaves the pass's thread running anyway; stop() awaits it instead.
                self._pass = asyncio.ensure_future(asyncio.to_thread(self._reconcile_until_stopped))
                await asyncio.shield(self._pass)
                if self._more:  # writes left for the next pass: run it at once (Event: loop thread only)
                    self.cache.changed.set()
            except ResourcesReplaced as error:
                if self.on_resources_back is not None:
                    log.info("%s; restarting the watches", error)
                    self.restart_requested = True
                    self.on_resources_back()
                    return
                self._crds_replaced = False
            except ResourceMissing as error:
                self.metrics.errors.inc()
                delay = backoff.failed()
                log.error("%s; retrying in %.0fs", error, delay)
                await asyncio.sleep(delay)
                continue
            except PermanentError as error:
                self.metrics.errors.inc()
                log.error("reconcile cannot proceed: %s", error)
                # Not a retry backoff: retrying sooner cannot help; the next pass comes a period later.
                await asyncio.sleep(period)
            except Exception:  # noqa: BLE001 - the loop outlives every failure; the next pass retries
                self.metrics.errors.inc()
                log.exception("reconcile pass failed, retrying")
                await asyncio.sleep(failed_passes.failed())
            else:
                failed_passes.succeeded()
            if backoff.failing:
                backoff.succeeded()
                if self.on_resources_back is not None:
                    # kopf looks for served resources again only when a CRD changes; the last
                    # change (Established) can come before discovery serves the resource, and
                    # then kopf never watches it again: the cache would stay empty for good.
                    log.info("the RobotJob and Cell resources are back; restarting the watches")
                    self.restart_requested = True
                    self.on_resources_back()
                    return
                log.info("the RobotJob and Cell resources are back; reconciling again")

    def _cells_in_scope(self, cells: list[Cell]) -> list[Cell]:
        """A namespaced operator leaves alone cells held by jobs it cannot see.

        Cells are cluster-scoped and may be shared by operators watching other
        namespaces; without this, a claim by an unseen job looks abandoned.
        """
        if not self.settings.namespaces:
            return cells
        watched = set(self.settings.namespaces)
        return [c for c in cells if not c.current_job or c.current_job.split("/")[0] in watched]

    def _quotas_in_scope(self, quotas: list[QuotaObject]) -> list[QuotaObject]:
        """A namespaced operator applies (and writes the status of) only its own tenants' CellQuotas."""
        if not self.settings.namespaces:
            return quotas
        watched = set(self.settings.namespaces)
        return [q for q in quotas if q.namespace in watched]

    def _watch_crds(self, now: datetime, every: timedelta) -> None:
        """Every replica, leader or not, notices its CRDs deleted or replaced (at most every ``every``).

        kopf may miss a CRD's return (see ``on_resources_back``); a standby that missed it
        would lead with an empty cache, and a delete and create between two looks (a new
        uid) is a return all the same. Raises ResourceMissing while a CRD is gone and
        ResourcesReplaced once they are all back and served.
        """
        if self._crd_check_off or (self._crds_checked_at is not None and now - self._crds_checked_at < every):
            return
        try:
            uids = self.api.crd_uids()
        except PermanentError as error:  # RBAC without `get` on CRDs (kopf alone needs list/watch): warn, go on
            log.warning("%s; this replica does not watch its CRDs for a re-creation (kopf may miss one)", error)
            self._crd_check_off = True
            return
        self._crds_checked_at = now
        if len(uids) < 2 or (self._crd_uids is not None and uids != self._crd_uids):
            self._crds_replaced = True
        if len(uids) < 2:
            self._crds_checked_at = None  # look again on the next pass
            self.api.check_resources()  # raises ResourceMissing, naming what is not served
            raise ResourceMissing("the RobotJob or Cell CRD is missing (kubectl apply -f crds/)")
        self._crd_uids = uids
        if self._crds_replaced:
            self._crds_checked_at = None
            self.api.check_resources()  # created again, but served yet? (ResourceMissing until it is)
            raise ResourcesReplaced("the RobotJob/Cell CRDs were created again")

    def _reconcile_until_stopped(self) -> None:
        """One pass; one that outlived the stop's grace and then failed on the closed API ends quietly.

        Such a pass is still a task of the loop when kopf ends: kopf re-raises the
        exception of every task it finds done, and the operator's exit became a crash
        (``TransientError: the operator is stopping``, seen in a loaded test run).
        """
        try:
            self.reconcile()
        except Exception as error:  # noqa: BLE001 - re-raised unless the operator is stopping
            if not self._stopping:
                raise
            log.info("the reconcile pass that outlived the stop ended: %s", error)

    def reconcile(self) -> None:
        """One pass (runs in a worker thread: the client is blocking)."""
        now = self.clock()
        duration = timedelta(seconds=self.settings.lease_duration)
        self._watch_crds(now, duration / 3)
        # Renew at a third of the lease duration, not on every pass: passes come in bursts.
        if self.leading and self._renewed_at and now - self._renewed_at < duration / 3:
            leading = True
        else:
            leading = self.api.hold_lease(
                self.settings.lease_namespace, self.settings.lease_name, duration, now
            )
            self._renewed_at = now if leading else None
            if leading:
                try:
                    self.api.check_resources()  # at the renewal cadence: one cheap GET every few seconds
                except ResourceMissing:
                    self._renewed_at = None  # check again on the next try
                    raise
        if leading != self.leading:
            log.info("%s leadership", "gained" if leading else "lost")
            self.memory = Memory()
            self._quotas_listed = False
        self.leading = leading
        self.metrics.leader.set(1 if leading else 0)
        if not leading:
            return
        started = time.perf_counter()
        if not self._quotas_listed:
            try:
                self.cache.load_quotas(self.api.list_quotas())
            except PermanentError as error:  # an RBAC without cellquotas: schedule unrationed, say why
                log.error("%s; CellQuotas are not applied", error)
            self._quotas_listed = True
        jobs, cells = self.cache.snapshot()
        cells = self._cells_in_scope(cells)
        quotas = self._quotas_in_scope(self.cache.quota_snapshot())
        self.api.writing(True)
        try:
            # With a store of outputs, a TTL delete waits for the job's upload (``artifact_removal``).
            timing = replace(self.settings.timing, outputs_store=self.api.outputs_bucket is not None)
            outcome = reconcile_once(jobs, cells, now, timing, self.api, self.memory, self.limits,
                                     quotas)
        finally:
            self.api.writing(False)
        self.cache.remember(outcome.jobs_written, outcome.cells_written, outcome.deleted)
        self._more = outcome.more
        self.metrics.observe(outcome, jobs, cells, now)
        self.metrics.pass_seconds.observe(time.perf_counter() - started)
        if outcome.bound or outcome.conflicts or outcome.more:
            log.info("pass: bound %d, %d conflict(s), %d write(s) in %.2fs%s",
                     len(outcome.bound), outcome.conflicts, outcome.writes, time.perf_counter() - started,
                     "; more queue writes next pass" if outcome.more else "")
