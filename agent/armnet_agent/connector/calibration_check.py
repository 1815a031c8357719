"""Compare the servos' EEPROM calibration with the cell's calibration file.

Why: a servo recalibrated or swapped outside armnet moves to different angles
for the same goal; the cell must then say "calibration not present" with the
reason, and never be silently "fixed". ``calibration_mismatches`` is the pure
decision (table-tested); ``read_calibration`` is the one read path the node
agent's health probe calls when no job holds the bus (docs/connector.md,
"Calibration check").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

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


def read_calibration(port: str, cell_motors: Mapping[str, Any]) -> dict[int, tuple[int, int, int] | None]:
    """The calibration registers of each servo on ``port``, by id (None: it did not answer).

    ``cell_motors`` is the cell's motor table (name -> ``lerobot.motors.Motor``).
    Reads only, through the real LeRobot/feetech SDK path, torque untouched; the
    caller must hold the bus (no job running). Raises ``ConnectionError`` if the
    port cannot be opened.
    """
    from lerobot.motors.feetech import FeetechMotorsBus  # the SDK: heavy, only when a probe runs

    bus = FeetechMotorsBus(port=port, motors=dict(cell_motors))
    bus.connect(handshake=False)
    try:
        held: dict[int, tuple[int, int, int] | None] = {}
        for name, motor in bus.motors.items():
            try:
                values = [int(bus.read(reg, name, normalize=False, num_retry=2)) for reg in CALIBRATION_REGISTERS]
            except (ConnectionError, RuntimeError):  # a servo that does not answer is a mismatch, not a crash
                held[motor.id] = None
                continue
            held[motor.id] = (values[0], values[1], values[2])
        return held
    finally:
        bus.disconnect(disable_torque=False)
