"""Serve a byte-level request handler on a pseudo-terminal, from one thread.

This module owns the pty and nothing else: it knows no protocol. Design points
from running the real SDK against a pty (docs/reference/feetech-lerobot.md, §1 and §8):

- the slave is put in raw mode at creation and a slave fd is kept open for the
  server's lifetime and never read, so the master never sees ``EIO`` when the
  client closes, and the client may re-open the port as often as it likes;
- replies go out in one write, promptly: LeRobot waits only ~50 ms, and a late
  reply would be taken as the answer to the client's next request;
- writes are non-blocking: when nobody drains the slave, replies are dropped as
  on a bus with no listener, instead of wedging the thread;
- the serving thread asks for real-time scheduling (``SCHED_FIFO`` at the lowest
  real-time priority), else a lower nice value (best effort: both need
  ``CAP_SYS_NICE``), because a reply that misses the client's deadline is a
  failed transaction. A real servo answers on its own CPU; on a loaded 2-core
  test host a nice value alone still let replies miss LeRobot's ~16 ms packet
  timeout. The thread sleeps in ``select`` between requests, so the boost costs
  the machine nothing, and the kernel's real-time throttling bounds it if it
  ever spun;
- work that nobody waits for is done once the line is quiet: the handler may
  keep a request that gets no reply for later, and ``on_quiet`` runs when no
  byte has come for ``quiet_after_s`` after such a request. Why: a real servo
  applies a write on its own CPU, while this thread, woken at real-time
  priority on the CPU where the host is still finishing its write call, would
  preempt the host for the whole handling (~250-350 us of Python per 6-servo
  SYNC_WRITE on a 2-core host; the connector's reply waited behind it in half
  of the proxied goal writes).
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import select
import struct
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

log = logging.getLogger(__name__)

#: How long a reply may wait for room in the pty buffer before it is dropped.
WRITE_DEADLINE_S = 0.05
#: How long the line must stay quiet, after a request that got no reply, before ``on_quiet`` runs:
#: longer than the host takes to finish its write call (direct or through the connector).
QUIET_AFTER_S = 0.001
#: ``SCHED_FIFO`` priority requested for the serving thread (the lowest real-time one).
REALTIME_PRIORITY = 1
#: Nice value requested for the serving thread when real-time scheduling is refused.
BOOSTED_NICE = -10
#: The interpreter's thread switch interval in a process that only simulates a cell (the
#: interpreter's default is 5 ms): see ``interleave_serving_threads``.
SERVING_SWITCH_INTERVAL_S = 0.0002
#: Linux ``TCGETS2``: reads ``struct termios2``, whose ``c_ospeed`` (bytes 40..44) is the
#: line speed in bit/s, also for the non-standard rates pyserial sets with ``BOTHER``.
_TCGETS2 = 0x802C542A
_TERMIOS2_SIZE = 44


class PtyServer:
    """A pty whose master side answers with ``handler(data, now) -> reply``."""

    def __init__(
        self,
        handler: Callable[[bytes, float], bytes],
        *,
        link_path: str | Path | None = None,
        latency_s: float = 0.0,
        name: str = "armnet-sim",
        clock: Callable[[], float] = time.monotonic,
        boost_priority: bool = True,
        on_quiet: Callable[[], None] | None = None,
        quiet_after_s: float = QUIET_AFTER_S,
    ) -> None:
        self._handler = handler
        self._on_quiet = on_quiet
        self._quiet_after_s = quiet_after_s
        self._boost_priority = boost_priority
        self._link = Path(link_path) if link_path is not None else None
        self.latency_s = latency_s
        self._name = name
        self._clock = clock
        self._master: int | None = None
        self._slave: int | None = None
        self._device: str | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()

    @property
    def device(self) -> str:
        """The ``/dev/pts/N`` path of the slave side."""
        if self._device is None:
            raise RuntimeError(f"{self._name} is not started; call start() first")
        return self._device

    @property
    def port(self) -> str:
        """The path to hand to pyserial / LeRobot: the stable symlink if one was asked for."""
        return str(self._link) if self._link is not None and self._device else self.device

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def line_speed(self) -> int | None:
        """The baud rate the client last set on the port (bit/s); None when unknown.

        A pty carries bytes at any speed, but the client's setting is visible on
        the shared line discipline, so the simulator can model a servo that
        listens at another rate.
        """
        fd = self._slave
        if fd is None:
            return None
        try:
            raw = fcntl.ioctl(fd, _TCGETS2, bytes(_TERMIOS2_SIZE))
        except OSError:
            return None
        speed: int = struct.unpack_from("I", raw, 40)[0]
        return speed or None

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError(f"{self._name} is already started")
        master, slave = os.openpty()
        tty.setraw(slave)
        _set_line_speed(slave, termios.B1000000)  # the servos' factory rate, for clients that never set one
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._device = os.ttyname(slave)
        self._wake_r, self._wake_w = os.pipe()
        if self._link is not None:
            self._link.parent.mkdir(parents=True, exist_ok=True)
            if self._link.is_symlink() or self._link.exists():
                self._link.unlink()
            self._link.symlink_to(self._device)
        self._stopping.clear()
        self._thread = threading.Thread(target=self._serve, name=self._name, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread, close the pty and remove the symlink; idempotent."""
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stopping.set()
            assert self._wake_w is not None
            os.write(self._wake_w, b"x")
            thread.join(timeout=5)
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = None
        if self._link is not None and self._link.is_symlink():
            self._link.unlink()
        self._device = None

    def _serve(self) -> None:
        if self._boost_priority:
            _boost_this_thread()
        master, wake = self._master, self._wake_r
        assert master is not None and wake is not None
        quiet_due = False  # a request got no reply: ``on_quiet`` runs once the line is quiet
        while not self._stopping.is_set():
            readable, _, _ = select.select([master, wake], [], [], self._quiet_after_s if quiet_due else None)
            if wake in readable:
                return
            if not readable:
                quiet_due = False
                self._run_on_quiet()
                continue
            try:
                data = os.read(master, 4096)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno == errno.EIO:  # no slave open at this instant
                    # A poll for the next opener, not a retry of a failure (no backoff): a driver that
                    # opens the port must find it answering at once.
                    time.sleep(0.001)
                    continue
                raise
            if not data:
                continue
            try:
                reply = self._handler(data, self._clock())
            except Exception:  # noqa: BLE001 - a bad frame must never kill the bus thread
                log.exception("%s: handler failed; request dropped", self._name)
                continue
            quiet_due = self._on_quiet is not None and not reply
            if reply:
                if self.latency_s > 0:
                    time.sleep(self.latency_s)
                self._write(master, reply)

    def _run_on_quiet(self) -> None:
        assert self._on_quiet is not None
        try:
            self._on_quiet()
        except Exception:  # noqa: BLE001 - as a bad frame: never kill the bus thread
            log.exception("%s: quiet-line work failed", self._name)

    def _write(self, master: int, reply: bytes) -> None:
        deadline = time.monotonic() + WRITE_DEADLINE_S
        view = memoryview(reply)
        while view:
            try:
                sent = os.write(master, view)
                view = view[sent:]
            except BlockingIOError:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    log.warning(
                        "%s: nobody reads the port; %d reply bytes dropped", self._name, len(view)
                    )
                    return
                select.select([], [master], [], remaining)


def _set_line_speed(fd: int, speed: int) -> None:
    attrs = termios.tcgetattr(fd)
    attrs[4] = attrs[5] = speed
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


def interleave_serving_threads() -> None:
    """In a process of its own, let the simulator's threads take turns at a fine grain.

    Real servos on two buses answer in parallel, each on its own CPU. Here every arm's
    serving thread shares one interpreter lock: a read on one arm that arrived while the
    other arm's thread applied a kept goal write (~300 us of Python) waited for it, up
    to the interpreter's default 5 ms switch interval, and a bimanual control loop saw
    that wait as noise in its read times. Process-wide, so only the simulator's own
    processes call it (``SimulatedCellProcess``'s child, ``armnet sim``), never a process
    that merely hosts a simulator among other work.
    """
    sys.setswitchinterval(SERVING_SWITCH_INTERVAL_S)


def _boost_this_thread() -> None:
    """Real-time scheduling for this thread, else a lower nice value; ignore if neither is permitted.

    Both are per thread on Linux (``0`` names the calling thread). Inside a
    container without ``CAP_SYS_NICE`` both are refused and the thread runs as
    any other.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
        return
    except (PermissionError, OSError) as exc:
        log.debug("no real-time scheduling for the simulator thread: %s", exc)
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BOOSTED_NICE)
    except (PermissionError, OSError) as exc:
        log.debug("cannot raise the simulator thread's priority: %s", exc)
