"""Runs one launched job to its end: live output, deadline, grace, kill, result.

The launched job is anything with two byte streams, ``wait`` and ``kill``: a
local subprocess (:class:`SubprocessJob`) or a container (see
``armnet_launch.container``). The supervisor owns the clock: at the
deadline it calls ``hooks.on_deadline`` (the host asks the connector to trip
the interlock and open the grace window) and at the end of the grace window it
kills the job, polling often enough that the kill lands within a second.
"""

from __future__ import annotations

import codecs
import logging
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import IO, Protocol

from armnet_core import JobResult

from armnet_launch.supervise.observe import OutputEvent, OutputObserver, Stream
from armnet_launch.supervise.outcome import RunFacts, assemble_result

log = logging.getLogger(__name__)

# How often the supervisor re-checks the clock and the job; bounds kill latency.
POLL_INTERVAL_S = 0.05
# How long to wait for the engine to report the exit of a job just killed.
DRAIN_TIMEOUT_S = 3.0
# After the exit, the output is read to its end: the readers may be far behind (a
# burst of lines right before the exit, a slow host callback, a container log re-read)
# and the last lines carry the result marker. The wait ends early only when the readers
# take no line for the job's ``drain_stall_s`` (default DRAIN_STALL_S: a pipe some
# leftover process holds open but never writes to), and in any case after DRAIN_LIMIT_S.
DRAIN_STALL_S = 15.0
DRAIN_LIMIT_S = 120.0
READ_CHUNK = 64 * 1024


class LaunchedJob(Protocol):
    """A started job process, wherever it runs.

    It may also have ``drain_stall_s``: how long its output may stay silent after the
    exit before the supervisor stops waiting for the rest (None: no such bound, for
    output that always ends, e.g. a log stream re-read in one long call).
    """

    def stdout_chunks(self) -> Iterator[bytes]: ...

    def stderr_chunks(self) -> Iterator[bytes]: ...

    def wait(self, timeout: float) -> int | None:
        """The exit code, or None if still running after ``timeout`` seconds."""
        ...

    def kill(self) -> None:
        """Kill the job and everything it started, now."""
        ...


@dataclass(frozen=True)
class SupervisorLimits:
    timeout_seconds: float
    grace_seconds: float = 10.0
    tail_chars: int = 16 * 1024
    #: Seconds of the job's clock already spent (a job adopted after an agent restart).
    already_elapsed_s: float = 0.0


def _noop_event(event: OutputEvent) -> None:
    return None


def _noop() -> None:
    return None


@dataclass
class JobHooks:
    """Host callbacks. They run on supervisor threads and must not block long."""

    on_event: Callable[[OutputEvent], None] = _noop_event
    on_deadline: Callable[[], None] = _noop
    # Opens the grace window of a graceful cancel (the interlock then names the cancel,
    # not a timeout); ``None``: ``on_deadline`` does.
    on_cancel: Callable[[], None] | None = None
    # Set by the host to end the grace window early (e.g. the connector's
    # grace-expired callback) or to cancel the job outright.
    kill_now: threading.Event = field(default_factory=threading.Event)
    cancel: threading.Event = field(default_factory=threading.Event)
    # Set by the host to stop the job the way a timeout does (``on_deadline``, then
    # the kill at the end of the grace window), but ending ``cancelled``.
    cancel_gracefully: threading.Event = field(default_factory=threading.Event)


class SubprocessJob:
    """A job run as a local child process in its own session (process group)."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self._proc = proc

    @classmethod
    def start(
        cls, command: Sequence[str], env: Mapping[str, str], cwd: str | None = None
    ) -> SubprocessJob:
        proc = subprocess.Popen(
            list(command),
            env=dict(env),
            cwd=cwd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,  # its own process group, so kill() reaches grandchildren
        )
        return cls(proc)

    @property
    def pid(self) -> int:
        return self._proc.pid

    def stdout_chunks(self) -> Iterator[bytes]:
        return _chunks(self._proc.stdout)

    def stderr_chunks(self) -> Iterator[bytes]:
        return _chunks(self._proc.stderr)

    def wait(self, timeout: float) -> int | None:
        try:
            return self._proc.wait(timeout=max(timeout, 0.0))
        except subprocess.TimeoutExpired:
            return None

    def kill(self) -> None:
        try:
            os.killpg(self._proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def _chunks(stream: IO[bytes] | None) -> Iterator[bytes]:
    if stream is None:
        return
    reader = getattr(stream, "read1", stream.read)
    while True:
        chunk = reader(READ_CHUNK)
        if not chunk:
            return
        yield chunk


def iter_lines(chunks: Iterator[bytes]) -> Iterator[str]:
    """Decode a byte stream into lines (keeping a last unterminated line)."""
    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
    pending = ""
    for chunk in chunks:
        pending += decoder.decode(chunk)
        *lines, pending = pending.split("\n")
        yield from lines
    pending += decoder.decode(b"", final=True)
    if pending:
        yield pending


def supervise(job: LaunchedJob, limits: SupervisorLimits, hooks: JobHooks | None = None) -> JobResult:
    """Follow ``job`` until it ends (or is killed) and return its ``JobResult``."""
    hooks = hooks or JobHooks()
    observer = OutputObserver(limits.tail_chars)
    lock = threading.Lock()
    lines_read = [0]
    started_at = datetime.now(UTC)
    start = time.monotonic() - limits.already_elapsed_s

    def pump(stream: Stream, chunks: Iterator[bytes]) -> None:
        try:
            for line in iter_lines(chunks):
                with lock:
                    event = observer.feed(stream, line)
                try:
                    hooks.on_event(event)
                except Exception:  # noqa: BLE001 - a host display bug must not stop the job's output
                    log.exception("output callback failed")
                with lock:
                    lines_read[0] += 1
        except Exception:  # noqa: BLE001 - a broken stream ends that stream only
            log.exception("reading the job's %s failed", stream.value)

    readers = [
        threading.Thread(target=pump, args=(Stream.STDOUT, job.stdout_chunks()), daemon=True),
        threading.Thread(target=pump, args=(Stream.STDERR, job.stderr_chunks()), daemon=True),
    ]
    for reader in readers:
        reader.start()

    deadline = start + limits.timeout_seconds
    kill_at = deadline + limits.grace_seconds
    deadline_passed = killed = cancelled = False
    exit_code: int | None = None
    killed_at: datetime | None = None
    while exit_code is None:
        now = time.monotonic()
        if hooks.cancel.is_set():
            cancelled = True
            job.kill()
            killed_at = datetime.now(UTC)
            exit_code = job.wait(DRAIN_TIMEOUT_S)
            break
        if not deadline_passed and not cancelled and hooks.cancel_gracefully.is_set():
            cancelled = True
            deadline_passed = True
            kill_at = min(kill_at, now + limits.grace_seconds)
            _open_grace(hooks, cancelled=True)
        if not deadline_passed and now >= deadline:
            deadline_passed = True
            _open_grace(hooks)
        if deadline_passed and (now >= kill_at or hooks.kill_now.is_set()):
            killed = True
            job.kill()
            killed_at = datetime.now(UTC)
            exit_code = job.wait(DRAIN_TIMEOUT_S)
            break
        next_check = kill_at if deadline_passed else deadline
        exit_code = job.wait(min(POLL_INTERVAL_S, max(next_check - now, 0.0)))

    # The job ended when it was killed (the engine may take a while to report the exit)
    # or now; draining its output afterwards is not part of its run time.
    finished_at = killed_at or datetime.now(UTC)

    def progress() -> int:
        with lock:
            return lines_read[0]

    _drain(readers, progress, getattr(job, "drain_stall_s", DRAIN_STALL_S))
    with lock:
        facts = RunFacts(
            exit_code=exit_code,
            timeout_seconds=limits.timeout_seconds,
            grace_seconds=limits.grace_seconds,
            deadline_passed=deadline_passed,
            killed_after_grace=killed,
            cancelled=cancelled,
            has_return_value=observer.has_return_value,
            return_value=observer.return_value,
            traceback=observer.traceback,
            stdout_tail=observer.stdout_tail.text(),
            stderr_tail=observer.stderr_tail.text(),
            started_at=started_at,
            finished_at=finished_at,
        )
    return assemble_result(facts)


def _drain(readers: Sequence[threading.Thread], progress: Callable[[], int], stall_s: float | None) -> None:
    """Wait until the readers reach the end of the job's output (see ``DRAIN_STALL_S``)."""
    began = last_change = time.monotonic()
    seen = progress()
    for reader in readers:
        while reader.is_alive():
            reader.join(POLL_INTERVAL_S)
            now, count = time.monotonic(), progress()
            if count != seen:
                seen, last_change = count, now
            stalled = stall_s is not None and now - last_change > stall_s
            if stalled or now - began > DRAIN_LIMIT_S:
                log.warning("stopped reading the job's output %.0f s after its exit (%s); "
                            "the result is built from what was read", now - began,
                            "no new line" if stalled else "time limit")
                return


def _open_grace(hooks: JobHooks, cancelled: bool = False) -> None:
    opener = hooks.on_cancel if cancelled and hooks.on_cancel is not None else hooks.on_deadline
    try:
        opener()
    except Exception:  # noqa: BLE001 - the kill at grace end must happen regardless
        log.exception("opening the grace window failed")


def infra_failure(message: str, limits: SupervisorLimits) -> JobResult:
    """The result of a job that could not run (engine error, bad image, no cell)."""
    now = datetime.now(UTC)
    return assemble_result(
        RunFacts(
            exit_code=None,
            timeout_seconds=limits.timeout_seconds,
            grace_seconds=limits.grace_seconds,
            infra_error=message,
            started_at=now,
            finished_at=now,
        )
    )
