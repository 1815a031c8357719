"""Builders shared by the simulator's real-stack tests (LeRobot objects for a simulated arm)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from armnet_sim import RemoteArm, SimulatedArm
from lerobot.motors import Motor, MotorCalibration, MotorNormMode
from lerobot.motors.feetech import FeetechMotorsBus

Arm = SimulatedArm | RemoteArm


def lerobot_motors(arm: Arm) -> dict[str, Motor]:
    return {
        spec.name: Motor(spec.id, "sts3215", MotorNormMode(spec.norm_mode))
        for spec in arm.motors.values()
    }


def lerobot_calibration(arm: Arm) -> dict[str, MotorCalibration]:
    return {
        name: MotorCalibration(
            id=c.id,
            drive_mode=c.drive_mode,
            homing_offset=c.homing_offset,
            range_min=c.range_min,
            range_max=c.range_max,
        )
        for name, c in arm.calibration.items()
    }


def a_feetech_bus(arm: Arm, *, calibrated: bool = True) -> FeetechMotorsBus:
    """The real LeRobot bus, built the way ``SOFollower`` builds it."""
    return FeetechMotorsBus(
        port=arm.port,
        motors=lerobot_motors(arm),
        calibration=lerobot_calibration(arm) if calibrated else None,
    )


def wait_until(condition: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    """Poll ``condition`` until it holds; the result is asserted by the caller."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


#: What LeRobot raises when a reply did not arrive within its ~50 ms timeout.
_TIMEOUT_MARKERS = ("There is no status packet", "Missing motor IDs")


def _is_timeout(exc: BaseException | None) -> bool:
    """True when ``exc`` or what it wraps is LeRobot reporting a missing reply."""
    while exc is not None:
        if any(marker in str(exc) for marker in _TIMEOUT_MARKERS):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


class Steady:
    """The real bus, with calls retried when the *client* missed its timeout.

    The SDK reads the port, then checks its 50 ms deadline; on a loaded CI
    machine the test process can be descheduled between the two for longer than
    the deadline while the simulator's reply already sits in the pty, and the
    real SDK then reports a timeout. Real hardware behaves the same under such
    load. Positive-path tests go through this wrapper so they test behaviour,
    not the machine's load; fault tests use the bare bus.
    """

    def __init__(self, bus: FeetechMotorsBus, attempts: int = 5) -> None:
        self.raw = bus
        self._attempts = attempts

    def __getattr__(self, name: str) -> Any:
        value = self._retry(lambda: getattr(self.raw, name), name)
        if not callable(value):
            return value
        return lambda *args, **kwargs: self._retry(lambda: value(*args, **kwargs), name)

    def _retry(self, fn: Callable[[], Any], name: str) -> Any:
        for attempt in range(1, self._attempts + 1):
            try:
                return fn()
            except (ConnectionError, RuntimeError) as exc:
                if attempt == self._attempts or not _is_timeout(exc):
                    raise
                handler = self.raw.port_handler
                if name == "connect" and handler.is_open:
                    handler.closePort()
                elif handler.is_open:
                    # The reply the client gave up on may still arrive: drop it, or the
                    # SDK (which never flushes input) takes it as the next answer.
                    time.sleep(0.06)
                    handler.ser.reset_input_buffer()
        raise AssertionError("unreachable")
