"""The STS3215 control table: where each register lives and how it is encoded.

Addresses, sizes, areas and sign bits follow LeRobot 0.4.4's
``lerobot/motors/feetech/tables.py`` so that what the real ``FeetechMotorsBus``
reads and writes lands where it expects. Default values are plausible factory
values for an STS3215 (12 V); only the ones LeRobot checks (model, firmware,
limits, homing offset) matter to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

MODEL_NUMBER_STS3215 = 777
RESOLUTION = 4096
#: Registers are a plain 256-byte array: any READ the SDK can express is answered.
MEMORY_SIZE = 256


class Area(Enum):
    """Where a register lives: EEPROM survives a power cycle (when saved), RAM does not."""

    EEPROM = "eeprom"
    RAM = "ram"
    FACTORY = "factory"


@dataclass(frozen=True)
class Register:
    name: str
    address: int
    size: int
    area: Area
    read_only: bool = False
    sign_bit: int | None = None
    default: int = 0


_E, _R, _F = Area.EEPROM, Area.RAM, Area.FACTORY

REGISTERS: tuple[Register, ...] = (
    Register("Firmware_Major_Version", 0, 1, _E, read_only=True, default=3),
    Register("Firmware_Minor_Version", 1, 1, _E, read_only=True, default=10),
    Register("Model_Number", 3, 2, _E, read_only=True, default=MODEL_NUMBER_STS3215),
    Register("ID", 5, 1, _E, default=1),
    Register("Baud_Rate", 6, 1, _E, default=0),
    Register("Return_Delay_Time", 7, 1, _E, default=250),
    Register("Response_Status_Level", 8, 1, _E, default=1),
    Register("Min_Position_Limit", 9, 2, _E, default=0),
    Register("Max_Position_Limit", 11, 2, _E, default=4095),
    Register("Max_Temperature_Limit", 13, 1, _E, default=70),
    Register("Max_Voltage_Limit", 14, 1, _E, default=140),
    Register("Min_Voltage_Limit", 15, 1, _E, default=40),
    Register("Max_Torque_Limit", 16, 2, _E, default=1000),
    Register("Phase", 18, 1, _E, default=12),
    Register("Unloading_Condition", 19, 1, _E, default=44),
    Register("LED_Alarm_Condition", 20, 1, _E, default=47),
    Register("P_Coefficient", 21, 1, _E, default=32),
    Register("D_Coefficient", 22, 1, _E, default=32),
    Register("I_Coefficient", 23, 1, _E, default=0),
    Register("Minimum_Startup_Force", 24, 2, _E, default=16),
    Register("CW_Dead_Zone", 26, 1, _E, default=1),
    Register("CCW_Dead_Zone", 27, 1, _E, default=1),
    Register("Protection_Current", 28, 2, _E, default=500),
    Register("Angular_Resolution", 30, 1, _E, default=1),
    Register("Homing_Offset", 31, 2, _E, sign_bit=11, default=0),
    Register("Operating_Mode", 33, 1, _E, default=0),
    Register("Protective_Torque", 34, 1, _E, default=20),
    Register("Protection_Time", 35, 1, _E, default=200),
    Register("Overload_Torque", 36, 1, _E, default=80),
    Register("Velocity_closed_loop_P_proportional_coefficient", 37, 1, _E, default=10),
    Register("Over_Current_Protection_Time", 38, 1, _E, default=200),
    Register("Velocity_closed_loop_I_integral_coefficient", 39, 1, _E, default=200),
    Register("Torque_Enable", 40, 1, _R, default=0),
    Register("Acceleration", 41, 1, _R, default=0),
    Register("Goal_Position", 42, 2, _R, sign_bit=15, default=0),
    Register("Goal_Time", 44, 2, _R, default=0),
    Register("Goal_Velocity", 46, 2, _R, sign_bit=15, default=0),
    Register("Torque_Limit", 48, 2, _R, default=1000),
    Register("Lock", 55, 1, _R, default=1),
    Register("Present_Position", 56, 2, _R, read_only=True, sign_bit=15),
    Register("Present_Velocity", 58, 2, _R, read_only=True, sign_bit=15),
    Register("Present_Load", 60, 2, _R, read_only=True, sign_bit=10),
    Register("Present_Voltage", 62, 1, _R, read_only=True, default=120),
    Register("Present_Temperature", 63, 1, _R, read_only=True, default=28),
    Register("Status", 65, 1, _R, read_only=True),
    Register("Moving", 66, 1, _R, read_only=True),
    Register("Present_Current", 69, 2, _R, read_only=True),
    Register("Goal_Position_2", 71, 2, _R, read_only=True),
    Register("Moving_Velocity_Threshold", 80, 1, _F, default=50),
    Register("DTs", 81, 1, _F, default=32),
    Register("Velocity_Unit_factor", 82, 1, _F, default=1),
    Register("Hts", 83, 1, _F, default=20),
    Register("Maximum_Velocity_Limit", 84, 1, _F, default=254),
    Register("Maximum_Acceleration", 85, 1, _F, default=254),
    Register("Acceleration_Multiplier", 86, 1, _F, default=0),
)

BY_NAME: dict[str, Register] = {r.name: r for r in REGISTERS}
EEPROM_END = 40  # addresses below this are EEPROM; 80..86 (factory) persist too


def _read_only_mask() -> bytes:
    mask = bytearray(MEMORY_SIZE)
    for reg in REGISTERS:
        if reg.read_only:
            mask[reg.address : reg.address + reg.size] = b"\x01" * reg.size
    # Address 2 (byte order) and the gaps of the RAM area are not writable.
    for addr in (2, *range(50, 55), 64, 67, 68, *range(73, 80), *range(87, MEMORY_SIZE)):
        mask[addr] = 1
    return bytes(mask)


READ_ONLY_MASK = _read_only_mask()


def is_persistent(address: int) -> bool:
    """EEPROM and factory bytes are the ones a power cycle keeps (if saved)."""
    return address < EEPROM_END or 80 <= address < 87


def encode_sign_magnitude(value: int, sign_bit: int) -> int:
    """LeRobot's encoding: magnitude below ``sign_bit``, the sign in that bit."""
    limit = (1 << sign_bit) - 1
    if abs(value) > limit:
        raise ValueError(f"{value} does not fit in sign-magnitude with sign bit {sign_bit}")
    return ((1 << sign_bit) if value < 0 else 0) | abs(value)


def decode_sign_magnitude(raw: int, sign_bit: int) -> int:
    magnitude = raw & ((1 << sign_bit) - 1)
    return -magnitude if raw & (1 << sign_bit) else magnitude


def default_memory(servo_id: int) -> bytearray:
    """A fresh servo's memory image, with its bus id."""
    mem = bytearray(MEMORY_SIZE)
    for reg in REGISTERS:
        value = reg.default
        if reg.sign_bit is not None:
            value = encode_sign_magnitude(value, reg.sign_bit)
        mem[reg.address : reg.address + reg.size] = value.to_bytes(reg.size, "little")
    mem[BY_NAME["ID"].address] = servo_id
    return mem
