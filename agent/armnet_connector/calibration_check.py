"""Compare the servos' EEPROM calibration with the cell's calibration file.

Why: a servo recalibrated or swapped outside armnet moves to different angles
for the same goal; the cell must then say "calibration not present" with the
reason, and never be silently "fixed". ``calibration_mismatches`` is the pure
decision (table-tested); ``read_calibration`` is the one read path the node
agent's health probe calls when no job holds the bus (docs/connector.md,
"Calibration check"): plain ``scservo_sdk`` reads, so the probe never loads LeRobot.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from .block_read import read_block
from .reply_window import use_lerobot_reply_window

#: The EEPROM registers that hold a servo's calibration, in tuple order.
CALIBRATION_REGISTERS = ("Homing_Offset", "Min_Position_Limit", "Max_Position_Limit")


@dataclass(frozen=True)
class CalibrationMismatch:
    """One servo register whose EEPROM value is not the cell's (``read`` None: the servo did not answer)."""

    motor_id: int
    register: str
    expected: int
    read: int | None

    def describe(self) -> str:
        if self.read is None:
            return f"servo {self.motor_id}: {self.register} could not be read (expected {self.expected})"
        return f"servo {self.motor_id}: {self.register} is {self.read}, the cell's calibration says {self.expected}"


def calibration_mismatches(
    expected: Mapping[int, tuple[int, int, int]], read: Mapping[int, tuple[int, int, int] | None]
) -> list[CalibrationMismatch]:
    """Every register of every expected servo whose read value differs, by servo id then register order.

    A servo missing from ``read`` (or read as None) mismatches on every register;
    servos read but not in ``expected`` are not the cell's business here.
    """
    found: list[CalibrationMismatch] = []
    for motor_id in sorted(expected):
        held = read.get(motor_id)
        for index, register in enumerate(CALIBRATION_REGISTERS):
            want = int(expected[motor_id][index])
            got = None if held is None else int(held[index])
            if got != want:
                found.append(CalibrationMismatch(motor_id, register, want, got))
    return found


#: STS3215 addresses of those registers (two bytes each), as in LeRobot's control table.
CALIBRATION_ADDRESSES = {"Homing_Offset": 31, "Min_Position_Limit": 9, "Max_Position_Limit": 11}
#: The one contiguous read that covers them (addresses 9 through 32).
CALIBRATION_BLOCK_START = min(CALIBRATION_ADDRESSES.values())
CALIBRATION_BLOCK_LENGTH = max(CALIBRATION_ADDRESSES.values()) + 2 - CALIBRATION_BLOCK_START
#: Homing_Offset is sign-magnitude, its sign at bit 11 (LeRobot's STS encoding table).
HOMING_OFFSET_SIGN_BIT = 11
#: The line speed of the cell's Feetech bus (LeRobot's default for these servos).
BAUD_RATE = 1_000_000
#: Extra tries per servo: a loaded machine can miss a reply (LeRobot's reads use 2; the idle
#: probe can afford more, and a read that never answers says nothing about calibration).
READ_RETRIES = 5


def _sign_magnitude(value: int, sign_bit: int) -> int:
    magnitude = value & ((1 << sign_bit) - 1)
    return -magnitude if (value >> sign_bit) & 1 else magnitude


def read_calibration(
    port: str, motor_ids: Iterable[int], *, baudrate: int = BAUD_RATE
) -> dict[int, tuple[int, int, int] | None]:
    """The calibration registers of each servo on ``port``, by id (None: it did not answer).

    Plain ``scservo_sdk`` reads (protocol 0, no LeRobot): the node agent's idle health
    probe calls this, and must stay light. Values as LeRobot's ``read(...,
    normalize=False)`` gives them (Homing_Offset's sign decoded). Reads only, torque
    untouched; the caller must hold the bus (no job running). Raises
    ``ConnectionError`` if the port cannot be opened.
    """
    from scservo_sdk import PacketHandler, PortHandler

    handler = PortHandler(port)
    try:
        opened = handler.openPort()
    except OSError as exc:  # pyserial's SerialException
        raise ConnectionError(f"could not open the servo bus at {port}: {exc}") from None
    if not opened:
        raise ConnectionError(f"could not open the servo bus at {port}")
    try:
        handler.setBaudRate(baudrate)
        use_lerobot_reply_window(handler)
        packets = PacketHandler(0)
        return {motor_id: read_servo_calibration(packets, handler, motor_id) for motor_id in sorted(set(motor_ids))}
    finally:
        handler.closePort()


def read_servo_calibration(packets: Any, handler: Any, motor_id: int) -> tuple[int, int, int] | None:
    """One servo's calibration registers, in ``CALIBRATION_REGISTERS`` order, or None when it does not answer.

    One block read of a length no other read asks for (``block_read``): a late reply to
    an earlier read cannot pass for a calibration value. The connector's check of a
    calibration job's servos reads through it too.
    """
    block = read_block(packets, handler, motor_id, CALIBRATION_BLOCK_START, CALIBRATION_BLOCK_LENGTH,
                       retries=READ_RETRIES)
    if block is None:
        return None
    homing, low, high = (_word(block, CALIBRATION_ADDRESSES[r] - CALIBRATION_BLOCK_START)
                         for r in CALIBRATION_REGISTERS)
    return _sign_magnitude(homing, HOMING_OFFSET_SIGN_BIT), low, high


def _word(block: list[int], offset: int) -> int:
    """A two-byte register from a block read: protocol 0 (STS servos) sends the low byte first."""
    return block[offset] | block[offset + 1] << 8
