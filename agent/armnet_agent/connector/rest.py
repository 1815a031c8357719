"""``return_to_rest``: a slow, speed-limited move of every arm to its rest pose.

This module owns the motion plan's execution on a bus (raw ticks, so the
customer's normalisation never matters). The rest pose is the arm's
``rest_pose`` or the middle of each calibrated range; the plan comes from the
pure ``safety.plan_rest_steps``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from .config import ArmConfig, MotorRange
from .safety import plan_rest_steps

log = logging.getLogger(__name__)

TICK_S = 0.02
SETTLE_TOLERANCE_TICKS = 25
#: A busy host or a noisy cable drops the odd packet; the connector's own moves retry.
RETRIES = 3
CONNECT_ATTEMPTS = 3


def rest_pose(arm: ArmConfig, ranges: dict[str, MotorRange]) -> dict[str, int]:
    """Raw goal per motor: the configured pose, else the middle of each calibrated range."""
    pose = {motor: r.middle for motor, r in ranges.items()}
    pose.update(arm.rest_pose or {})
    return pose


@contextmanager
def private_bus(arm: ArmConfig, ranges: dict[str, MotorRange]) -> Iterator[Any]:
    """A bus of the connector's own on the arm's device, for when no job bus is connected."""
    from lerobot.motors import Motor, MotorNormMode
    from lerobot.motors.feetech import FeetechMotorsBus

    motors = {m: Motor(r.id, arm.motor_model, MotorNormMode.RANGE_M100_100) for m, r in ranges.items()}
    bus = FeetechMotorsBus(port=arm.port, motors=motors)
    for attempt in range(1, CONNECT_ATTEMPTS + 1):
        try:
            bus.connect()
            break
        except (ConnectionError, RuntimeError) as exc:
            if bus.is_connected:
                bus.disconnect(disable_torque=False)
            if attempt == CONNECT_ATTEMPTS:
                raise
            log.warning("return_to_rest: connecting to %s failed (%s); retrying", arm.port, exc)
    try:
        yield bus
    finally:
        # Torque stays on: the arm holds its rest pose instead of dropping.
        bus.disconnect(disable_torque=False)


def move_to_rest(bus: Any, target: dict[str, int], speed_ticks_per_s: float) -> None:
    """Walk ``bus`` to ``target`` (raw ticks) at ``speed_ticks_per_s`` and wait until it settles."""
    motors = [m for m in target if m in bus.motors]
    if not motors:
        return
    present = {m: int(v) for m, v in bus.sync_read("Present_Position", motors, normalize=False, num_retry=RETRIES).items()}
    # Hold where we are before torque comes on, so a stale goal cannot make the arm jump.
    bus.sync_write("Goal_Position", present, normalize=False, num_retry=RETRIES)
    bus.enable_torque(motors, num_retry=RETRIES)
    goal = {m: target[m] for m in motors}
    for step in plan_rest_steps(present, goal, speed_ticks_per_s * TICK_S):
        bus.sync_write("Goal_Position", step, normalize=False, num_retry=RETRIES)
        time.sleep(TICK_S)
    settle_deadline = time.monotonic() + 3.0
    while time.monotonic() < settle_deadline:
        now = bus.sync_read("Present_Position", motors, normalize=False, num_retry=RETRIES)
        if all(abs(int(now[m]) - goal[m]) <= SETTLE_TOLERANCE_TICKS for m in motors):
            return
        time.sleep(TICK_S)
    log.warning("return_to_rest: the arm did not settle within 3 s of the last step")
