"""``SimulatedBus``: a ``ServoBus`` served on a pty, safe to inspect from tests.

It glues the pure pieces (frame parser, servo bus) to the ``PtyServer`` thread
and guards them with one lock, so a test can read positions or inject a fault
while the real SDK talks to the bus from another thread.

A lone broadcast SYNC_WRITE (the goal write of every control tick, which no
servo answers) is kept and applied with its arrival time once the line is
quiet, before the next request, or before anyone inspects the servos, so
every observer sees the same servo state as if it had been applied at once.
Why: real servos apply a write on their own CPU; applied at once here, it held
the host's CPU (see ``pty_server``) while the host was still in its write call.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

from .bus_model import ServoBus
from .lifecycle import StartStop
from .protocol import FrameParser, is_lone_sync_write
from .pty_server import PtyServer
from .servo import Servo, ServoFaults

#: Writes kept for a quiet line at most: a sender that never pauses (a flood) has each one
#: applied at once past this, so it cannot grow the simulator's memory.
MAX_DEFERRED_WRITES = 64

T = TypeVar("T")


class SimulatedBus(StartStop):
    """A set of simulated servos on one serial line (one pty)."""

    def __init__(
        self,
        servos: Iterable[Servo],
        *,
        latency_ms: float = 0.0,
        link_path: str | Path | None = None,
        name: str = "armnet-sim",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._model = ServoBus(servos)
        self._parser = FrameParser()
        #: Received writes not applied yet: (bytes, arrival time, the line speed then), in order.
        self._deferred: list[tuple[bytes, float, int | None]] = []
        self._server = PtyServer(
            self._on_bytes,
            link_path=link_path,
            latency_s=latency_ms / 1000.0,
            name=name,
            clock=clock,
            on_quiet=self._on_quiet,
        )

    # -- lifecycle ----------------------------------------------------------------------

    def start(self) -> SimulatedBus:
        self._server.start()
        return self

    def stop(self) -> None:
        self._server.stop()

    @property
    def port(self) -> str:
        """The device path to give pyserial or ``FeetechMotorsBus(port=...)``."""
        return self._server.port

    @property
    def device(self) -> str:
        return self._server.device

    @property
    def running(self) -> bool:
        return self._server.running

    # -- configuration and inspection ----------------------------------------------------

    @property
    def latency_ms(self) -> float:
        return self._server.latency_s * 1000.0

    def set_latency_ms(self, latency_ms: float) -> None:
        """Delay every reply by this much; over ~50 ms LeRobot gives up on each request."""
        if latency_ms < 0:
            raise ValueError("latency_ms must be >= 0")
        self._server.latency_s = latency_ms / 1000.0

    def inspect(self, fn: Callable[[ServoBus, float], T]) -> T:
        """Run ``fn(bus_model, now)`` under the bus lock: the one way to touch servo state."""
        with self._lock:
            self._apply_deferred()
            return fn(self._model, self._clock())

    def set_faults(self, servo_id: int, faults: ServoFaults) -> None:
        self.inspect(lambda bus, _now: _require(bus, servo_id).set_faults(faults))

    def power_cycle(self) -> None:
        """Unsaved EEPROM changes and all RAM settings are lost, as when the supply is cut."""

        def cycle(bus: ServoBus, now: float) -> None:
            for servo in bus:
                servo.power_cycle(now)

        self.inspect(cycle)

    def _on_bytes(self, data: bytes, now: float) -> bytes:
        with self._lock:
            line_baud = self._server.line_speed()
            if self._parser.idle and len(self._deferred) < MAX_DEFERRED_WRITES and is_lone_sync_write(data):
                self._deferred.append((data, now, line_baud))
                return b""
            self._apply_deferred()
            return self._handle(data, now, line_baud)

    def _on_quiet(self) -> None:
        with self._lock:
            self._apply_deferred()

    def _apply_deferred(self) -> None:
        """Apply the kept writes in arrival order, each at its own time; caller holds the lock."""
        deferred, self._deferred = self._deferred, []
        for data, now, line_baud in deferred:
            self._handle(data, now, line_baud)

    def _handle(self, data: bytes, now: float, line_baud: int | None) -> bytes:
        self._model.line_baud = line_baud
        frames = self._parser.feed(data, now)
        return b"".join(self._model.handle(frame, now) for frame in frames)


def _require(bus: ServoBus, servo_id: int) -> Servo:
    servo = bus.servo(servo_id)
    if servo is None:
        raise KeyError(f"no servo with id {servo_id} on this bus")
    return servo
