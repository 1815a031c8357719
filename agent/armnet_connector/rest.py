"""The connector's own moves on an arm: return to rest, and torque off.

This module owns the cell's bus: a ``FeetechMotorsBus`` the connector builds
from the cell's description alone (the arm's device, the motor names and ids of
the cell's calibration file, the arm's motor model), never from a job's bus
object, names or calibration. A job that named its motors differently, or gave
them other ids, cannot make the rest pose, torque off or a restore land on other
servos. It also owns the execution of the rest walk (raw ticks; the walk is the
pure ``safety.RestWalk``) and of the register restore (the rules are ``restore``'s),
and their outcomes, read back from the servos.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from .block_read import read_block
from .config import ArmConfig, MotorRange
from .restore import (
    READ_RETRIES,
    WRITE_ROUNDS,
    RestoreBlock,
    RestoreOutcome,
    judge_restore,
    restore_plan,
    servos_of,
)
from .retry import CONNECT_RETRY_DELAYS_S, retry_lost_replies
from .safety import RestWalk

log = logging.getLogger(__name__)

TICK_S = 0.02
#: How far (raw ticks) a servo may end from its rest goal and the rest still count as reached.
SETTLE_TOLERANCE_TICKS = 25
SETTLE_WAIT_S = 3.0
#: A busy host or a noisy cable drops the odd packet; the connector's own moves retry.
RETRIES = 3
#: The handshake of the cell's own bus is tried as often as a job's connect (``retry``).
CONNECT_ATTEMPTS = len(CONNECT_RETRY_DELAYS_S) + 1
#: A port that does not open is missing (unplugged, or gone with its simulator), not slow: the
#: handshake's patience would only hold a stop's grace window up (2.8 s per arm, at every stop).
OPEN_ATTEMPTS = 3
TORQUE_ENABLE = "Torque_Enable"


@dataclass(frozen=True)
class RestReport:
    """Where one arm ended after a return to rest, read back from its servos (raw ticks)."""

    arm: str
    reached: bool
    #: Servo goal minus where it ended, per cell motor name.
    errors: dict[str, int] = field(default_factory=dict)
    tolerance: int = SETTLE_TOLERANCE_TICKS
    #: Why the move could not be made at all (no calibration, the bus failed), else "".
    failure: str = ""

    def message(self) -> str:
        if self.failure:
            return f"arm {self.arm!r} did not return to rest: {self.failure}"
        if self.reached:
            return f"arm {self.arm!r} is at its rest pose"
        worst = max(self.errors, key=lambda m: abs(self.errors[m]))
        return (
            f"arm {self.arm!r} ended {abs(self.errors[worst])} ticks from its rest pose on {worst!r} "
            f"(tolerance {self.tolerance}); an operator should check the cell before the next job"
        )


def rest_pose(arm: ArmConfig, ranges: dict[str, MotorRange]) -> dict[str, int]:
    """Raw goal per motor: the configured pose, else the middle of each calibrated range."""
    pose = {motor: r.middle for motor, r in ranges.items()}
    pose.update({m: v for m, v in (arm.rest_pose or {}).items() if m in ranges})
    return pose


@contextmanager
def cell_bus(arm: ArmConfig, ranges: dict[str, MotorRange], *, handshake: bool = True) -> Iterator[Any]:
    """A bus of the connector's own on the arm's device, built from the cell's description only.

    The caller holds the arm's device lock, so a job's bus on the same device
    sends nothing meanwhile. ``handshake=False`` skips the ping of every servo
    (torque off must work even when a servo no longer answers).
    """
    from lerobot.motors import Motor, MotorNormMode
    from lerobot.motors.feetech import FeetechMotorsBus

    motors = {m: Motor(r.id, arm.motor_model, MotorNormMode.RANGE_M100_100) for m, r in ranges.items()}
    bus = FeetechMotorsBus(port=arm.port, motors=motors)
    for attempt in range(1, CONNECT_ATTEMPTS + 1):
        try:
            bus.connect(handshake=handshake)
            break
        except (ConnectionError, RuntimeError) as exc:
            if bus.is_connected:
                bus.port_handler.closePort()
            # LeRobot's ConnectionError: the port did not open; RuntimeError: a servo missed the handshake.
            if attempt >= (OPEN_ATTEMPTS if isinstance(exc, ConnectionError) else CONNECT_ATTEMPTS):
                raise
            log.warning("connecting the cell's bus on %s failed (%s); retrying", arm.port, exc)
            # Past the lost reply first (as a job's connect, ``retry``): asked again at once, the
            # handshake's next ping can take the late reply of this one and miss a servo again;
            # and as patient as a job's connect (a second of starved CPU loses every ping of
            # three quick attempts: a scripted reset failed so under the suite's load).
            time.sleep(CONNECT_RETRY_DELAYS_S[attempt - 1])
    try:
        yield bus
    finally:
        # Torque stays as the caller left it: after a rest the arm holds its pose instead of dropping.
        bus.port_handler.closePort()


def torque_off(bus: Any) -> bool:
    """Turn torque off on every servo of the cell's ``bus``; True once read back as off.

    One sync write (no status packet to wait for, so a servo that stopped
    answering cannot hold it up), then a read back, repeated a few times.
    """
    motors = list(bus.motors)
    for _ in range(RETRIES):
        bus.sync_write(TORQUE_ENABLE, {m: 0 for m in motors}, normalize=False)
        try:
            state = bus.sync_read(TORQUE_ENABLE, motors, normalize=False, num_retry=1)
        except (ConnectionError, RuntimeError) as exc:
            log.warning("torque off: could not read the torque state back (%s)", exc)
            continue
        if not any(int(v) for v in state.values()):
            return True
    return False


def switch_torque_on(bus: Any, motors: list[str], *, on_lost_reply: Callable[[], None],
                     before_retry: Callable[[], None] | None = None) -> None:
    """Torque on for ``motors``: acknowledged writes, asked again the connector's way when a servo's reply is
    lost (``retry``: past the late reply). LeRobot's ``num_retry`` alone asks at once: a starved host lost
    all four of its tries on one servo, and a scripted reset failed its return to rest (CI run 20).
    The writes are absolute (``Torque_Enable``, ``Lock`` = 1): asking again changes nothing twice."""
    retry_lost_replies(bus, "rest's enable_torque", lambda: bus.enable_torque(motors, num_retry=RETRIES),
                       on_retry=on_lost_reply, before_retry=before_retry)


def move_to_rest(
    bus: Any, arm_name: str, target: dict[str, int], speed_ticks_per_s: float, *, deadline: float | None = None,
    on_lost_reply: Callable[[], None] = lambda: None,
) -> RestReport:
    """Walk the cell's ``bus`` to ``target`` (raw ticks) at ``speed_ticks_per_s``, then read back where it ended.

    ``deadline`` (``time.monotonic()``) ends the walk and the settling early: at a
    job's end the grace window is the hard limit and torque off must still fit in
    it, so a walk cut short is reported as not reached, never waited out. A position
    read that lost a servo reply is asked again the connector's way (``retry``: past
    the late reply, which is dropped; LeRobot's own ``num_retry`` asks at once and takes
    the late reply as the answer), within ``deadline``; ``on_lost_reply`` counts each.
    """
    motors = [m for m in target if m in bus.motors]
    if not motors:
        return RestReport(arm_name, True)

    def in_time() -> None:
        if _past(deadline):
            raise TimeoutError("the stop's time for a rest ran out while a servo reply was lost")

    def positions() -> dict[str, int]:
        read = retry_lost_replies(
            bus, "rest's sync_read", lambda: bus.sync_read("Present_Position", motors, normalize=False),
            on_retry=on_lost_reply, before_retry=in_time,
        )
        return {m: int(v) for m, v in read.items()}

    if _past(deadline):  # torque is not even switched on for a walk that cannot take a step
        return RestReport(arm_name, False, failure="the stop's time for a rest ran out before it began")
    present = positions()
    # Hold where we are before torque comes on, so a stale goal cannot make the arm jump.
    bus.sync_write("Goal_Position", present, normalize=False, num_retry=RETRIES)
    switch_torque_on(bus, motors, on_lost_reply=on_lost_reply, before_retry=in_time)
    walk = RestWalk(present, {m: target[m] for m in motors}, speed_ticks_per_s)
    last_tick = time.monotonic()
    done = 0.0
    while done < 1.0 and not _past(deadline):
        time.sleep(TICK_S)
        now = time.monotonic()
        done = walk.advance(done, now - last_tick)
        last_tick = now
        bus.sync_write("Goal_Position", walk.at(done), normalize=False, num_retry=RETRIES)
    settle_deadline = time.monotonic() + SETTLE_WAIT_S
    if deadline is not None:
        settle_deadline = min(settle_deadline, deadline)
    while True:
        reached = positions()
        errors = {m: walk.goal[m] - reached[m] for m in motors}
        if all(abs(e) <= SETTLE_TOLERANCE_TICKS for e in errors.values()):
            return RestReport(arm_name, True, errors)
        if time.monotonic() >= settle_deadline:
            return RestReport(arm_name, False, errors)
        time.sleep(TICK_S)


def restore_registers(
    bus: Any, block: RestoreBlock, pending: Mapping[int, Mapping[str, int]], names: Mapping[int, str], *,
    on_lost_reply: Callable[[], None] = lambda: None, deadline: float | None = None,
) -> RestoreOutcome:
    """Write ``pending`` back on the cell's ``bus`` (a connected LeRobot bus whose motors are ``names``' values).

    Raises when the servos to restore cannot be held first (their torque state or
    positions cannot be read): nothing is written then, since a restored torque limit
    or speed on a servo still driving toward a goal would move the arm.
    """
    pending = {i: registers for i, registers in pending.items() if registers and i in names}
    before = _read_blocks(bus, block, sorted(pending), deadline)
    plan = restore_plan(pending, before)
    if plan:
        hold_in_place(bus, [names[i] for i in servos_of(plan)], on_lost_reply=on_lost_reply, deadline=deadline)
    after = dict(before)
    for _ in range(WRITE_ROUNDS):
        if not plan:
            break
        for register, values in plan.items():  # in RESTORE_ORDER: the plan keeps it
            bus.sync_write(register, {names[i]: v for i, v in values.items()}, normalize=False)
        after.update(_read_blocks(bus, block, servos_of(plan), deadline))
        if deadline is not None and time.monotonic() >= deadline:
            break
        plan = restore_plan(pending, after)
    return judge_restore(pending, before, after, names)


def hold_in_place(
    bus: Any, motors: list[str], *, on_lost_reply: Callable[[], None] = lambda: None, deadline: float | None = None,
) -> None:
    """Every motor with torque on gets its present position as its goal: what it drives toward is where it is."""
    if not motors:
        return

    def in_time() -> None:
        if deadline is not None and time.monotonic() >= deadline:
            raise TimeoutError("the stop's time ran out while a servo reply was lost")

    torque = retry_lost_replies(
        bus, "restore's torque read", lambda: bus.sync_read("Torque_Enable", motors, normalize=False),
        on_retry=on_lost_reply, before_retry=in_time,
    )
    driven = [m for m in motors if int(torque[m])]
    if not driven:
        return
    present = retry_lost_replies(
        bus, "restore's position read", lambda: bus.sync_read("Present_Position", driven, normalize=False),
        on_retry=on_lost_reply, before_retry=in_time,
    )
    bus.sync_write("Goal_Position", {m: int(v) for m, v in present.items()}, normalize=False)


def _read_blocks(
    bus: Any, block: RestoreBlock, ids: Sequence[int], deadline: float | None
) -> dict[int, Mapping[str, int] | None]:
    held: dict[int, Mapping[str, int] | None] = {}
    for servo_id in ids:
        data = read_block(bus.packet_handler, bus.port_handler, servo_id, block.start, block.length,
                          retries=READ_RETRIES, ignore_status_bits=True, deadline=deadline)
        held[servo_id] = None if data is None else block.decode(data)
    return held


def _past(deadline: float | None) -> bool:
    return deadline is not None and time.monotonic() >= deadline
