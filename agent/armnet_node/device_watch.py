"""Reads a cell's device paths every half second and keeps the cell's one device verdict.

The verdict (``node.device_health``) is what the Cell's ``HardwareReady``, the
kubelet device plugin's health and a running job's "device lost" stop all
follow; this thread only reads (``deviceplugin.facts``: stat calls, never the
bus) and tells the cell's worker when the verdict changes, so a lost device
reaches the Cell and the job within ``POLL_S + DEBOUNCE_S`` rather than at the
next heartbeat.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Sequence

from armnet_node.device_health import DEBOUNCE_S, POLL_S, DeviceState, observe
from armnet_node.deviceplugin.decide import DevicePath
from armnet_node.deviceplugin.facts import read_fact
from armnet_node.metrics import AgentMetrics

log = logging.getLogger(__name__)

#: A read that keeps failing (a bug behind ``paths``) logs its traceback at most this often (seconds).
FAILURE_LOG_EVERY_S = 60.0


class DeviceWatch:
    """One cell's device reads and verdict; ``on_change`` runs on the watch thread when the verdict changes."""

    def __init__(
        self, cell: str, paths: Callable[[], Sequence[DevicePath]], on_change: Callable[[DeviceState], None],
        metrics: AgentMetrics, *, poll_s: float = POLL_S, debounce_s: float = DEBOUNCE_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cell = cell
        self._paths = paths
        self._on_change = on_change
        self._metrics = metrics
        self._poll_s = poll_s
        self._debounce_s = debounce_s
        self._clock = clock
        self._state = DeviceState()
        #: One read at a time (the thread's, or a caller's ``poll``): the verdict advances in order.
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"armnet-devices-{cell}", daemon=True)
        #: When (``clock``) a failed read last logged its traceback; None: never, or read fine since.
        self._failure_logged_at: float | None = None
        self._failures_unlogged = 0

    @property
    def state(self) -> DeviceState:
        return self._state

    def plugin_health(self) -> str:
        """The device plugin's answer to the kubelet (``Healthy`` / ``Unhealthy``), from this verdict."""
        return self._state.plugin_health

    def start(self) -> DeviceWatch:
        self.tick()  # the verdict exists before the first heartbeat and the first device-plugin answer
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(2)
        with contextlib.suppress(KeyError):  # never read: no series to remove
            self._metrics.device_healthy.remove(self.cell)

    def poll(self) -> DeviceState:
        """Read the devices once and advance the verdict; ``on_change`` if it changed."""
        with self._lock:
            previous = self._state
            state = observe(previous, [read_fact(path) for path in self._paths()], self._clock(), self._debounce_s)
            self._state = state
        self._metrics.device_healthy.labels(cell=self.cell).set(0 if state.lost else 1)
        if (state.lost, state.problems) != (previous.lost, previous.problems):
            self._log(previous, state)
            try:
                self._on_change(state)
            except Exception:  # noqa: BLE001 - the watch must keep reading; the worker's pass acts again
                log.exception("cell %s: acting on the device verdict failed", self.cell)
        return state

    def _log(self, previous: DeviceState, state: DeviceState) -> None:
        if state.lost and not previous.lost:
            log.warning("cell %s: device lost: %s", self.cell, "; ".join(state.problems))
        elif state.problems and not previous.problems:
            log.info("cell %s: %s (lost if it lasts %g s)", self.cell, "; ".join(state.problems), self._debounce_s)
        elif previous.lost and not state.lost:
            log.info("cell %s: every device stayed present for %g s: no longer lost", self.cell, self._debounce_s)
        elif not state.problems and previous.problems:
            log.info("cell %s: every device is present%s", self.cell,
                     f" again (healthy once it stays so for {self._debounce_s:g} s)" if state.lost else "")

    def tick(self) -> None:
        """One read of the loop: a failure is retried at the next, its traceback logged at most once a minute."""
        try:
            self.poll()
        except Exception:  # noqa: BLE001 - a bad read (a path callable's bug) is retried next poll
            now = self._clock()
            if self._failure_logged_at is not None and now - self._failure_logged_at < FAILURE_LOG_EVERY_S:
                self._failures_unlogged += 1
                return
            log.warning("cell %s: reading its devices failed (%d more failures since the last report; "
                        "the verdict stays as it was)", self.cell, self._failures_unlogged, exc_info=True)
            self._failure_logged_at, self._failures_unlogged = now, 0
        else:
            self._failure_logged_at, self._failures_unlogged = None, 0

    def _loop(self) -> None:
        while not self._stop.wait(self._poll_s):
            self.tick()
