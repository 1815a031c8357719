"""The agent's upload queue: each ended job's output directory goes to the object store, once, whatever happens.

Level-based, like the rest of the agent. A job is *tracked* when its output directory is
made: a record ``<state>/uploads/<uid>.json`` (namespace, name, uid) is written before the
job can write a byte. A tracked job's output is taken when its runner says the terminal
status is written (``ready``), or when a sweep finds the RobotJob terminal or gone (the
agent was killed between the status and the upload, or in the middle of an upload, or
the job ended without this agent: the sweep runs at start and every ``SWEEP_PERIOD_S``).
A job a runner of this agent still runs is never taken (one deleted while its container is
in its grace window still writes). The record and the directory are removed only after the
output is stored and the job's status says so (or could never be: over the cap), so nothing
a job wrote is lost to a crash; the upload itself resumes
(a re-run skips what is stored with the same checksum). The cell's record of the job
(``HostPaths.record_dir``: the rollouts' pictures, the rollout history) goes with it,
under ``armnet-cell/``, and is removed with it.

Without an object store the output is removed once the job ended (it would fill the robot
host) and ``status.artifacts`` says so when the job had written something.

One thread uploads one job at a time: robot hosts have one uplink, and a job's cell is
released by its terminal status, not by its upload.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armnet_core.api import TERMINAL_PHASES
from armnet_core.backoff import Backoff, BackoffPolicy
from armnet_core.output_keys import job_prefix

from armnet_node.artifacts import (
    ObjectStore,
    OutputLimits,
    OutputTooLarge,
    StoreMisconfigured,
    StoreUnavailable,
    summary,
    upload_output,
)
from armnet_node.kube import AgentKube, Gone, KubeError
from armnet_node.metrics import AgentMetrics
from armnet_node.plan import HostPaths

log = logging.getLogger(__name__)

#: How often tracked jobs are checked against the API (a job that ended without its runner's word).
SWEEP_PERIOD_S = 60.0
#: The retry delays of an upload the store refused or did not answer.
RETRY = BackoffPolicy(first_s=5.0, max_s=300.0)


@dataclass(frozen=True)
class TrackedJob:
    """A job whose output directory exists on this host."""

    namespace: str
    name: str
    uid: str


class UploadQueue:
    """``track`` at launch, ``ready`` after the terminal status; ``run`` in the agent's thread."""

    def __init__(
        self, store: ObjectStore | None, paths: HostPaths, kube: AgentKube, metrics: AgentMetrics,
        limits: OutputLimits | None = None,
    ) -> None:
        self.store = store
        self.paths = paths
        self.kube = kube
        self.metrics = metrics
        self.limits = limits or OutputLimits()
        self.records = paths.state_dir / "uploads"
        self._lock = threading.Lock()
        #: Jobs a runner of this agent still runs: never taken, whatever the API says (a job deleted
        #: while its container is in its grace window still writes).
        self._live: set[str] = set()
        self._ready: set[str] = set()
        self._retry: dict[str, tuple[Backoff, float]] = {}  # uid -> (its backoff, not before this monotonic time)
        self._last_status: dict[str, dict[str, Any]] = {}
        self._wake = threading.Event()

    # -- the runners' side ----------------------------------------------------------------

    def track(self, job: TrackedJob) -> None:
        """Record the job before its output directory can hold anything (written atomically)."""
        self.records.mkdir(parents=True, exist_ok=True)
        record = self._record(job.uid)
        temporary = record.with_suffix(".tmp")
        with temporary.open("w") as file:
            file.write(json.dumps({"namespace": job.namespace, "name": job.name, "uid": job.uid}))
            file.flush()
            os.fsync(file.fileno())  # the record must survive a crash right after the job starts
        os.replace(temporary, record)
        with self._lock:
            self._live.add(job.uid)

    def ready(self, uid: str) -> None:
        """The job's terminal status is written: its output is final."""
        with self._lock:
            self._live.discard(uid)
            if self._record(uid).exists():  # the sweep may have taken it already
                self._ready.add(uid)
        self._wake.set()

    def pending_status(self, uid: str) -> dict[str, Any] | None:
        """``status.artifacts`` to write with the job's terminal status: ``Pending`` when the queue will
        write a final phase for it (it is tracked, and there is a store or something to discard).

        A client waiting for the job's result then knows to wait for the upload too.
        """
        if not self._record(uid).exists():
            return None
        if self.store is None and not _has_entries(self.paths.output_dir(uid)):
            return None
        return summary.pending()

    def released(self, uid: str) -> None:
        """The runner let go without a terminal status (the agent stops): the sweep decides."""
        with self._lock:
            self._live.discard(uid)

    # -- the queue's thread ---------------------------------------------------------------

    def run(self, stop: threading.Event) -> None:
        next_sweep = 0.0
        for stale in self.records.glob("*.tmp") if self.records.is_dir() else ():
            stale.unlink(missing_ok=True)  # a record half-written when the agent died: its job never started
        while not stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_sweep:
                    self._sweep()
                    next_sweep = now + SWEEP_PERIOD_S
                self.process_ready(stop)
            except Exception:  # noqa: BLE001 - the queue never dies of one pass (an API server away)
                log.warning("upload queue pass failed; retried", exc_info=True)
                next_sweep = min(next_sweep, now + RETRY.first_s)
            self._wake.wait(min(SWEEP_PERIOD_S, self._next_retry_in()))
            self._wake.clear()

    def process_ready(self, stop: threading.Event | None = None) -> None:
        """Take every ready job whose retry delay has passed, one at a time."""
        tracked = self.tracked()
        with self._lock:  # forget what has no record any more (taken, or removed by hand)
            uids = {job.uid for job in tracked}
            self._ready &= uids
            self._retry = {uid: due for uid, due in self._retry.items() if uid in uids}
        for job in tracked:
            if stop is not None and stop.is_set():
                break
            with self._lock:
                due = (job.uid in self._ready and job.uid not in self._live
                       and time.monotonic() >= self._retry.get(job.uid, (None, 0.0))[1])
            if due:
                self._take(job)
        with self._lock:
            self.metrics.outputs_pending.set(len(self._ready))

    def tracked(self) -> list[TrackedJob]:
        """Every job with a record, oldest first; a record that cannot be read is removed with a warning."""
        if not self.records.is_dir():
            return []
        found = []
        for record in sorted(self.records.glob("*.json"), key=_mtime):
            try:
                data = json.loads(record.read_text())
                found.append(TrackedJob(str(data["namespace"]), str(data["name"]), str(data["uid"])))
            except (OSError, ValueError, KeyError, TypeError) as exc:
                log.warning("upload record %s cannot be read (%s); removed", record, exc)
                record.unlink(missing_ok=True)
        return found

    def _sweep(self) -> None:
        """Mark ready every tracked job that the API shows ended or gone."""
        for job in self.tracked():
            with self._lock:
                if job.uid in self._ready or job.uid in self._live:
                    continue
            try:
                current = self.kube.read_job(job.namespace, job.name)
            except Gone:
                current = None
            except KubeError as exc:
                log.warning("upload sweep: cannot read robotjob %s/%s: %s", job.namespace, job.name, exc)
                continue
            ours = current is not None and (current.get("metadata") or {}).get("uid") == job.uid
            if not ours or ((current or {}).get("status") or {}).get("phase") in TERMINAL_PHASES:
                self.ready(job.uid)

    def _take(self, job: TrackedJob) -> None:
        directory = self.paths.output_dir(job.uid)
        if self.store is None:
            had_output = _has_entries(directory)  # the job's own: the cell's record goes quietly with it
            self._done(job, directory)
            self.metrics.outputs.labels(outcome="discarded" if had_output else "empty").inc()
            if had_output:
                self._write_status(job, summary.discarded())
            return
        prefix = job_prefix(job.namespace, job.uid)
        record = self.paths.record_dir(job.uid)
        if not directory.is_dir():  # removed by hand: still a final phase, and the cell's record stored
            log.warning("job %s/%s: its output directory %s is gone; only the cell's record is uploaded",
                        job.namespace, job.name, directory)
        self._write_status(job, summary.uploading(self.store.bucket, prefix))
        try:
            try:
                report = upload_output(directory, self.store, job.namespace, job.uid, self.limits, record=record)
            except OutputTooLarge as exc:
                # The job's output over the cap must not take the cell's record with it (a job could
                # otherwise erase the pictures of its own evaluation): the record alone is stored.
                if _has_entries(record):
                    stored = upload_output(None, self.store, job.namespace, job.uid, self.limits, record=record)
                    self._write_status(job, summary.failed(
                        f"{exc}; the job's output was removed and only the cell's record was stored",
                        location=summary.location(stored.bucket, stored.prefix)))
                else:
                    self._write_status(job, summary.failed(f"{exc}; nothing was stored and the output was removed"))
                self._done(job, directory)
                self.metrics.outputs.labels(outcome="too_large").inc()
                return
        except (StoreUnavailable, StoreMisconfigured) as exc:
            self._retry_later(job, prefix, str(exc),
                              "misconfigured" if isinstance(exc, StoreMisconfigured) else "unavailable")
            return
        except Exception as exc:  # noqa: BLE001 - an agent bug keeps the output and is retried, never lost
            log.exception("job %s/%s: the upload failed", job.namespace, job.name)
            self._retry_later(job, prefix, f"the agent could not upload the output ({type(exc).__name__}: {exc})",
                              "error")
            return
        if not self._write_status(job, summary.uploaded(report)):
            # Stored, but the job does not say so yet: kept, and taken again (what is stored is skipped).
            self._retry_later(job, prefix, "the upload finished but status.artifacts could not be written",
                              "error", write_status=False)
            return
        # Counted before the directory goes: whoever sees it gone sees the upload counted.
        self.metrics.outputs.labels(outcome="uploaded" if report.complete else "incomplete").inc()
        self.metrics.output_bytes.inc(report.uploaded_bytes)
        self._done(job, directory)
        log.info("job %s/%s: %d files (%d bytes) stored under %s", job.namespace, job.name,
                 len(report.artifacts), report.total_bytes, summary.location(report.bucket, report.prefix))

    def _retry_later(self, job: TrackedJob, prefix: str, error: str, reason: str, *,
                     write_status: bool = True) -> None:
        assert self.store is not None
        with self._lock:
            backoff = self._retry.get(job.uid, (RETRY.start(), 0.0))[0]
            wait_s = backoff.failed()
            self._retry[job.uid] = (backoff, time.monotonic() + wait_s)
        self.metrics.output_upload_failures.labels(reason=reason).inc()
        log.warning("job %s/%s: upload failed, retried in %.0f s: %s", job.namespace, job.name,
                    wait_s, error)
        if write_status:
            self._write_status(job, summary.retrying(self.store.bucket, prefix, error))

    def _done(self, job: TrackedJob, directory: Path) -> None:
        shutil.rmtree(directory, ignore_errors=True)
        shutil.rmtree(self.paths.record_dir(job.uid), ignore_errors=True)
        self._record(job.uid).unlink(missing_ok=True)
        with self._lock:
            self._ready.discard(job.uid)
            self._retry.pop(job.uid, None)
        self._last_status.pop(job.uid, None)

    def _write_status(self, job: TrackedJob, artifacts: dict[str, Any]) -> bool:
        """``status.artifacts`` of the job, when it changed; False only when it could not be written.

        The field is replaced whole (an earlier phase's message does not stay), and only on
        this job: a job deleted, or re-created under the same name meanwhile, is not this
        job's status any more, so either counts as done.
        """
        if self._last_status.get(job.uid) == artifacts:
            return True
        try:
            self.kube.set_job_status_field(job.namespace, job.name, job.uid, "artifacts", artifacts)
        except Gone:
            return True
        except KubeError as exc:
            log.warning("job %s/%s: status.artifacts not written: %s", job.namespace, job.name, exc)
            return False
        self._last_status[job.uid] = artifacts
        return True

    def _next_retry_in(self) -> float:
        with self._lock:
            waits = [at - time.monotonic() for uid, (_, at) in self._retry.items() if uid in self._ready]
        return max(min(waits, default=SWEEP_PERIOD_S), 0.05)

    def _record(self, uid: str) -> Path:
        return self.records / f"{uid}.json"


def _has_entries(directory: Path) -> bool:
    try:
        with os.scandir(directory) as entries:
            return any(True for _ in entries)
    except OSError:
        return False


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0
