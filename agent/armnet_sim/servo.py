"""One simulated STS3215: its memory image, its joint, and its injected faults.

The servo owns register semantics (read-only bytes, EEPROM persistence under
``Lock``, torque enable, goal clamping to the position limits) and derives the
``Present_*`` registers from the physics on every access. It is pure: time is
passed in, nothing here blocks or does I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace

from . import control_table as ct
from .physics import Drive, JointState, PhysicsParams, Telemetry, step, telemetry

_REG = ct.BY_NAME

#: Baud_Rate register value -> line speed (bit/s), the STS/SMS table LeRobot uses.
BAUD_RATES = {0: 1_000_000, 1: 500_000, 2: 250_000, 3: 128_000, 4: 115_200, 5: 57_600, 6: 38_400, 7: 19_200}
#: ERR-byte / Status bit the firmware sets when overload protection has cut the torque.
OVERLOAD_BIT = 0x20
#: Unloading_Condition bit: overload protection drops the torque.
UNLOAD_ON_OVERLOAD = 0x20


@dataclass(frozen=True)
class ServoFaults:
    """Faults injected by tests; the defaults are a healthy servo."""

    unplugged: bool = False  # no reply at all, writes do not arrive
    corrupt_checksum: bool = False  # every reply carries a wrong checksum
    error_bits: int = 0  # ORed into the ERR byte of every reply (e.g. ErrorBit.OVERLOAD)
    corrupt_next: int = 0  # the next N replies carry a wrong checksum (transient noise)
    drop_next: int = 0  # the next N replies are lost (requests are still obeyed)
    #: the next N replies each follow an empty status packet of this servo: the write
    #: acknowledgement that a loaded host's bus delivered after its writer gave up
    stale_ack_next: int = 0
    blocked: bool = False  # an obstacle holds the joint where it is (the drive pushes, nothing moves)


@dataclass(frozen=True)
class ServoCalibration:
    """The three EEPROM values a LeRobot calibration file sets on a servo."""

    homing_offset: int
    range_min: int
    range_max: int


class Servo:
    """Memory image plus joint state of one servo on the bus."""

    def __init__(
        self,
        servo_id: int,
        *,
        calibration: ServoCalibration | None = None,
        configured: Mapping[str, int] | None = None,
        params: PhysicsParams | None = None,
        now: float = 0.0,
    ) -> None:
        """``configured``: EEPROM values LeRobot's setup saved on a prepared cell, seeded with ``calibration``."""
        self.params = params or PhysicsParams()
        self.faults = ServoFaults()
        self._memory = ct.default_memory(servo_id)
        if calibration is not None:
            self._set(_REG["Homing_Offset"], calibration.homing_offset)
            self._set(_REG["Min_Position_Limit"], calibration.range_min)
            self._set(_REG["Max_Position_Limit"], calibration.range_max)
            # A calibrated servo has been through LeRobot's setup, whose configure()
            # leaves the return delay at its minimum (0) and saves the robot's gains
            # and limits (``configured``): what a prepared cell holds.
            self._set(_REG["Return_Delay_Time"], 0)
            for name, value in (configured or {}).items():
                reg = _REG.get(name)
                if reg is None or reg.area is ct.Area.RAM:
                    raise ValueError(f"{name!r} is not an EEPROM register of the STS3215 a setup can save")
                self._set(reg, value)
        # What a power cycle restores: the EEPROM as last saved with Lock = 0.
        self._saved = bytes(self._memory)
        self._pending: tuple[int, bytes] | None = None
        self._time = now
        # Overload protection: since when the load has stayed above Overload_Torque,
        # and whether the protection has tripped (torque dropped, bit 5 reported).
        self._overload_since: float | None = None
        self.overloaded = False
        low, high = self.limits()
        rest = (low + high) / 2 if high > low else 2048
        self.joint = JointState(
            position=float(round(rest) + self.homing_offset()),
            temperature=self.params.ambient_temperature,
        )
        self._power_on_ram()
        self._refresh()

    # -- identity and decoded registers -------------------------------------------------

    @property
    def servo_id(self) -> int:
        return self._memory[_REG["ID"].address]

    def get(self, name: str) -> int:
        """A register's value, sign-magnitude decoded where the table says so."""
        reg = _REG.get(name)
        if reg is None:
            raise KeyError(
                f"unknown register {name!r}; names follow LeRobot's STS3215 control table"
            )
        raw = int.from_bytes(self._memory[reg.address : reg.address + reg.size], "little")
        return raw if reg.sign_bit is None else ct.decode_sign_magnitude(raw, reg.sign_bit)

    def homing_offset(self) -> int:
        return self.get("Homing_Offset")

    def limits(self) -> tuple[int, int]:
        return self.get("Min_Position_Limit"), self.get("Max_Position_Limit")

    def torque_on(self) -> bool:
        return self.get("Torque_Enable") == 1

    def baudrate(self) -> int:
        """The line speed this servo listens and answers at (its Baud_Rate register)."""
        return BAUD_RATES.get(self.get("Baud_Rate"), 0)

    def present_position(self, now: float) -> int:
        self.advance(now)
        return self.get("Present_Position")

    # -- bus-facing access --------------------------------------------------------------

    def read(self, address: int, length: int, now: float) -> bytes:
        self.advance(now)
        end = min(ct.MEMORY_SIZE, address + length)
        data = bytes(self._memory[address:end])
        return data + bytes(length - len(data))

    def write(self, address: int, data: bytes, now: float) -> None:
        """Apply a WRITE: read-only bytes are skipped, EEPROM is saved only when unlocked."""
        self.advance(now)
        torque_before = self.torque_on()
        locked = self.get("Lock") != 0
        for offset, value in enumerate(data):
            addr = address + offset
            if addr >= ct.MEMORY_SIZE or ct.READ_ONLY_MASK[addr]:
                continue
            self._memory[addr] = value
            if ct.is_persistent(addr) and not locked:
                saved = bytearray(self._saved)
                saved[addr] = value
                self._saved = bytes(saved)
        if self.torque_on() and not torque_before:
            # Enabling torque holds the joint where it is, as the firmware does, and
            # clears a tripped overload protection (the host acknowledged it).
            self._set(_REG["Goal_Position"], self.get("Present_Position"))
            self.overloaded = False
            self._overload_since = None
        self._refresh()

    def reg_write(self, address: int, data: bytes) -> None:
        """REG_WRITE: buffer the write until ACTION."""
        self._pending = (address, bytes(data))

    def action(self, now: float) -> None:
        if self._pending is not None:
            address, data = self._pending
            self._pending = None
            self.write(address, data, now)

    def take_reply_faults(self) -> tuple[bool, bool]:
        """Faults for the reply about to be sent: (drop it, corrupt it); uses up transient ones."""
        faults = self.faults
        if faults.drop_next > 0:
            self.faults = replace(faults, drop_next=faults.drop_next - 1)
            return True, False
        if faults.corrupt_next > 0:
            self.faults = replace(faults, corrupt_next=faults.corrupt_next - 1)
            return False, True
        return False, faults.corrupt_checksum

    def take_stale_ack(self) -> bool:
        """True when a late write acknowledgement goes out before the reply about to be sent."""
        if self.faults.stale_ack_next <= 0:
            return False
        self.faults = replace(self.faults, stale_ack_next=self.faults.stale_ack_next - 1)
        return True

    def status_error(self) -> int:
        return (self.faults.error_bits | (OVERLOAD_BIT if self.overloaded else 0)) & 0x7F

    def replies_to_writes(self) -> bool:
        return self.get("Response_Status_Level") != 0

    # -- lifecycle ------------------------------------------------------------------------

    def power_cycle(self, now: float) -> None:
        """Drop RAM and unsaved EEPROM changes; the joint stays where it physically is."""
        self.advance(now)
        self._memory = bytearray(self._saved)
        self._pending = None
        self.overloaded = False
        self._overload_since = None
        self._power_on_ram()
        self._refresh()

    def saved_eeprom(self) -> bytes:
        """The memory image a power cycle restores (EEPROM as last saved with Lock = 0)."""
        return bytes(self._saved)

    def restore_saved(self, saved: bytes, now: float) -> None:
        """Power on with ``saved`` as the servo's saved EEPROM (a state file of an earlier run)."""
        if len(saved) != ct.MEMORY_SIZE:
            raise ValueError(f"a saved servo image has {ct.MEMORY_SIZE} bytes, got {len(saved)}")
        self._saved = bytes(saved)
        self.power_cycle(now)

    def factory_reset(self, now: float) -> None:
        """RESET instruction: factory EEPROM, same id, saved immediately."""
        servo_id = self.servo_id
        self.advance(now)
        self._memory = ct.default_memory(servo_id)
        self._saved = bytes(self._memory)
        self._power_on_ram()
        self._refresh()

    def move_by_hand(self, position: float, now: float) -> None:
        """Put the joint at a physical position (ticks), like a person moving a limp arm."""
        self.advance(now)
        self.joint = replace(self.joint, position=float(position), velocity=0.0)
        self._refresh()

    def set_faults(self, faults: ServoFaults) -> None:
        self.faults = faults
        self._refresh()

    # -- physics ------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        """Integrate the joint up to ``now`` and refresh the derived registers."""
        dt = now - self._time
        if dt > 0:
            self._time = now
            drive = self._drive()
            stepped = step(self.joint, drive, dt, self.params)
            if self.faults.blocked:  # the drive pushes (load, heat), the joint does not move
                stepped = replace(stepped, position=self.joint.position, velocity=0.0)
            self.joint = stepped
            self._protect(now)
            self._refresh()

    def _protect(self, now: float) -> None:
        """Overload protection: a load above Overload_Torque for Protection_Time drops the torque.

        As the STS3215 firmware does when Unloading_Condition has its overload bit:
        torque off, bit 5 (overload) in every status ERR byte and in Status until
        torque is enabled again. Load is in 0.1 % (capped by Torque_Limit),
        Overload_Torque in %, Protection_Time in 10 ms.
        """
        if not self.torque_on() or self.overloaded:
            self._overload_since = None
            return
        load = abs(telemetry(self.joint, self._drive(), self.params).load)
        if load <= self.get("Overload_Torque") * 10:
            self._overload_since = None
            return
        if self._overload_since is None:
            self._overload_since = now
        if now - self._overload_since >= self.get("Protection_Time") * 0.01:
            self.overloaded = True
            self._overload_since = None
            if self.get("Unloading_Condition") & UNLOAD_ON_OVERLOAD:
                self._set(_REG["Torque_Enable"], 0)

    def _drive(self) -> Drive:
        goal = self.get("Goal_Position")
        low, high = self.limits()
        if high > low:
            goal = max(low, min(high, goal))
        # Position mode only: in the other operating modes the joint is held still.
        torque = self.torque_on() and self.get("Operating_Mode") == 0
        return Drive(
            torque_on=torque,
            target=float(goal + self.homing_offset()) if torque else self.joint.position,
            speed_limit=abs(self.get("Goal_Velocity")),
            acceleration=self.get("Acceleration"),
            effort_limit=self.get("Torque_Limit"),
        )

    def _refresh(self) -> None:
        drive = self._drive()
        reading: Telemetry = telemetry(self.joint, drive, self.params)
        present = (round(self.joint.position) - self.homing_offset()) % ct.RESOLUTION
        self._set(_REG["Present_Position"], present)
        if not self.torque_on():
            # With torque off the goal follows the joint, so re-enabling never jumps.
            self._set(_REG["Goal_Position"], present)
        self._set(_REG["Present_Velocity"], _clip(reading.velocity, 15))
        self._set(_REG["Present_Load"], _clip(reading.load, 10))
        self._set(_REG["Present_Current"], min(reading.current, 0xFFFF))
        self._set(_REG["Present_Temperature"], max(0, min(255, reading.temperature)))
        self._set(_REG["Present_Voltage"], reading.voltage)
        self._set(_REG["Moving"], 1 if reading.moving else 0)
        self._set(_REG["Status"], self.status_error())
        self._set(_REG["Goal_Position_2"], self._memory_word(_REG["Goal_Position"]))

    def _power_on_ram(self) -> None:
        for reg in ct.REGISTERS:
            if reg.area is ct.Area.RAM:
                self._set(reg, reg.default)
        self._set(_REG["Torque_Limit"], self.get("Max_Torque_Limit"))

    def _memory_word(self, reg: ct.Register) -> int:
        return int.from_bytes(self._memory[reg.address : reg.address + reg.size], "little")

    def _set(self, reg: ct.Register, value: int) -> None:
        if reg.sign_bit is not None:
            value = ct.encode_sign_magnitude(value, reg.sign_bit)
        self._memory[reg.address : reg.address + reg.size] = value.to_bytes(reg.size, "little")


def _clip(value: int, sign_bit: int) -> int:
    limit = (1 << sign_bit) - 1
    return max(-limit, min(limit, value))
