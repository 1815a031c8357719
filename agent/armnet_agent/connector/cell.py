"""The state one connector shares between its connections: the cell of one job.

This module owns the shared facts (config, interlock, deadline, inputs, the
live objects of every connection, counters) and the cell-wide actions
(``return_to_rest``, ``reset``, releasing every device). Per-connection request
handling lives in ``session``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from .config import ConnectorConfig, MotorRange, read_calibration_file
from .deadline import Deadline
from .errors import RequestError
from .hardware import (
    CameraFactory,
    DeviceLocks,
    Handle,
    opencv_camera_factory,
    simulated_camera_factory,
)
from .inputs import CompletionMonitor, NeverComplete, OperatorInputs
from .interlock import Interlock, TripReason
from .motion import MotionGuard
from .rest import move_to_rest, private_bus, rest_pose

log = logging.getLogger(__name__)


@dataclass
class Counters:
    """Plain counters, exported as metrics later."""

    connections: int = 0
    requests: int = 0
    errors: int = 0
    safety_violations: int = 0
    objects_created: int = 0
    resets: int = 0
    #: Bus reads repeated after a lost servo reply (see ``retry``).
    bus_retries: int = 0
    #: Connections turned away at the per-socket cap or when no thread could serve them.
    connections_refused: int = 0
    #: ``accept`` failures (e.g. at the file-descriptor limit); the socket keeps serving.
    accept_errors: int = 0
    #: Connections closed for a request line over the line cap or the connector's buffer cap.
    oversized_requests: int = 0


@dataclass(frozen=True)
class RolloutEvent:
    kind: str  # "begin" | "end"
    at: float
    index: int | None = None
    total: int | None = None
    outcome_controls: bool | None = None


MAX_ROLLOUT_EVENTS = 1024


@dataclass
class CellState:
    config: ConnectorConfig
    inputs: OperatorInputs
    completion: CompletionMonitor = field(default_factory=NeverComplete)
    camera_factory: CameraFactory | None = None
    on_grace_expired: Callable[[], None] | None = None
    interlock: Interlock = field(default_factory=Interlock)
    locks: DeviceLocks = field(default_factory=DeviceLocks)
    counters: Counters = field(default_factory=Counters)
    # The latest rollout events only: a job may begin millions of rollouts.
    rollouts: deque[RolloutEvent] = field(default_factory=lambda: deque(maxlen=MAX_ROLLOUT_EVENTS))

    def __post_init__(self) -> None:
        self.ranges: dict[str, dict[str, MotorRange]] = {
            name: read_calibration_file(arm.calibration_file) if arm.calibration_file else {}
            for name, arm in self.config.arms.items()
        }
        if self.camera_factory is None:
            self.camera_factory = simulated_camera_factory() if self.config.simulated else opencv_camera_factory
        self.deadline = Deadline(
            self.config.timeout_seconds, self.config.grace_period_seconds, self.interlock, self.on_grace_expired
        )
        self.guard = MotionGuard(
            self.interlock, self.config.present_position_max_age_ms / 1000, self.counters,
            policy=self.config.safety_policy,
        )
        self._live: dict[int, Handle] = {}
        self._live_lock = threading.Lock()
        self._reset_lock = threading.Lock()

    # -- the live objects of every connection ---------------------------------------

    def register(self, handle: Handle) -> None:
        with self._live_lock:
            self._live[id(handle)] = handle
        self.counters.objects_created += 1

    def unregister(self, handle: Handle) -> None:
        with self._live_lock:
            self._live.pop(id(handle), None)

    def live_handles(self) -> list[Handle]:
        with self._live_lock:
            return list(self._live.values())

    def release(self, handle: Handle) -> None:
        """Disconnect ``handle``'s device if it is connected; never raises (logs instead)."""
        self.unregister(handle)
        try:
            with handle.lock:
                if not handle.obj.is_connected:
                    return
                if handle.class_name == "FeetechMotorsBus":
                    handle.obj.disconnect(disable_torque=self.config.disable_torque_on_shutdown)
                else:
                    handle.obj.disconnect()
        except Exception as exc:  # noqa: BLE001 — a dead device must not stop the others from being released
            log.warning("could not disconnect %s cleanly: %s: %s", handle.class_name, type(exc).__name__, exc)

    # -- cell-wide actions -------------------------------------------------------------

    def return_to_rest(self) -> None:
        refusal = self.interlock.refusal()
        if refusal is not None:
            raise RequestError(*refusal)
        for name, arm in self.config.arms.items():
            ranges = self.ranges.get(name) or {}
            if not ranges:
                raise RequestError(
                    "RuntimeError", f"arm {name!r} has no calibration file: the connector does not know its rest pose"
                )
            target = rest_pose(arm, ranges)
            lock = self.locks.get(arm.port)
            with lock:
                bus = self._connected_bus(name)
                if bus is not None:
                    move_to_rest(bus, target, self.config.rest_speed_ticks_per_second)
                    continue
                with private_bus(arm, ranges) as own:
                    move_to_rest(own, target, self.config.rest_speed_ticks_per_second)
            log.info("arm %s is at its rest pose", name)

    def _connected_bus(self, arm: str) -> Any:
        for handle in self.live_handles():
            if handle.arm == arm and handle.class_name == "FeetechMotorsBus" and handle.obj.is_connected:
                return handle.obj
        return None

    def reset(self) -> None:
        """Rest pose, then wait for an operator's confirmation; on timeout trip the interlock."""
        with self._reset_lock:
            self.counters.resets += 1
            self.return_to_rest()
            timeout = self.config.reset_timeout_seconds
            if self.inputs.wait_reset_confirmation(timeout):
                log.info("reset confirmed by the operator")
                return
            message = f"no operator confirmed the reset within {timeout:g} s"
            self.interlock.trip(TripReason.RESET_TIMEOUT, message)
            raise RequestError(
                "ResetTimeoutException",
                f"{message}; the cell's interlock is tripped. Finish up (save your data) and return.",
            )

    def record_rollout(self, event: RolloutEvent) -> None:
        self.rollouts.append(event)
        log.info("rollout %s index=%s total=%s", event.kind, event.index, event.total)

    @staticmethod
    def now() -> float:
        return time.time()
