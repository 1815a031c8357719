"""``SimulatedArm``: a simulated bus whose servos have motor names and a calibration.

This is the object tests, ``armnet sim`` and local runs hold: it starts the
pty, answers in LeRobot's vocabulary (motor names, normalised positions) and
injects faults by motor name.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

from .bus_model import ServoBus
from .calibration import MotorCalibration
from .lifecycle import StartStop
from .physics import PhysicsParams
from .protocol import ErrorBit
from .servo import Servo, ServoFaults
from .sim_bus import SimulatedBus

DEGREES = "degrees"
RANGE_0_100 = "range_0_100"
RANGE_M100_100 = "range_m100_100"
_MAX_RES = 4095
T = TypeVar("T")


@dataclass(frozen=True)
class MotorSpec:
    """A motor of the arm: its name, bus id and LeRobot ``MotorNormMode`` value."""

    name: str
    id: int
    norm_mode: str = DEGREES
    #: EEPROM values a prepared cell holds on this servo (seeded when it is calibrated).
    configured: tuple[tuple[str, int], ...] = ()


#: What LeRobot 0.4.4's ``SO101Follower.configure()`` saves in each servo's EEPROM (it
#: writes them inside ``torque_disabled()``, whose ``Lock=0`` makes them persist): an
#: SO-101 that LeRobot has set up and calibrated holds these.
SO101_CONFIGURED = (("P_Coefficient", 16), ("I_Coefficient", 0), ("D_Coefficient", 32))
#: The gripper's too: half torque, half current, 25 % overload torque, "to avoid burnout".
SO101_GRIPPER_CONFIGURED = (
    *SO101_CONFIGURED, ("Max_Torque_Limit", 500), ("Protection_Current", 250), ("Overload_Torque", 25),
)

SO101_MOTORS: tuple[MotorSpec, ...] = (
    MotorSpec("shoulder_pan", 1, configured=SO101_CONFIGURED),
    MotorSpec("shoulder_lift", 2, configured=SO101_CONFIGURED),
    MotorSpec("elbow_flex", 3, configured=SO101_CONFIGURED),
    MotorSpec("wrist_flex", 4, configured=SO101_CONFIGURED),
    MotorSpec("wrist_roll", 5, configured=SO101_CONFIGURED),
    MotorSpec("gripper", 6, RANGE_0_100, configured=SO101_GRIPPER_CONFIGURED),
)


class SimulatedArm(StartStop):
    """One arm: named STS3215 servos on their own pty, seeded from a calibration."""

    def __init__(
        self,
        motors: Sequence[MotorSpec] = SO101_MOTORS,
        calibration: Mapping[str, MotorCalibration] | None = None,
        *,
        name: str = "arm",
        latency_ms: float = 0.0,
        link_path: str | Path | None = None,
        physics: PhysicsParams | None = None,
        clock: Callable[[], float] = time.monotonic,
        state_file: str | Path | None = None,
    ) -> None:
        unknown = set(calibration or {}) - {m.name for m in motors}
        if unknown:
            raise ValueError(f"calibration names motors this arm does not have: {sorted(unknown)}")
        self.name = name
        self.motors: dict[str, MotorSpec] = {m.name: m for m in motors}
        self.calibration: dict[str, MotorCalibration] = dict(calibration or {})
        now = clock()
        servos = [
            Servo(
                m.id,
                calibration=self.calibration[m.name].servo_calibration()
                if m.name in self.calibration
                else None,
                configured=dict(m.configured),
                params=physics,
                now=now,
            )
            for m in motors
        ]
        self.bus = SimulatedBus(
            servos,
            latency_ms=latency_ms,
            link_path=link_path,
            name=f"armnet-sim-{name}",
            clock=clock,
        )

    # -- lifecycle ----------------------------------------------------------------------

        self.state_file = Path(state_file) if state_file is not None else None
        if self.state_file is not None and self.state_file.exists():
            self._load_state(self.state_file)

    def start(self) -> SimulatedArm:
        self.bus.start()
        return self

    def stop(self) -> None:
        self.bus.stop()
        if self.state_file is not None:
            self._save_state(self.state_file)

    # -- the EEPROM state file: what a power cycle keeps, across simulator restarts -----

    def _save_state(self, path: Path) -> None:
        images = self.bus.inspect(lambda bus, _now: {str(s.servo_id): s.saved_eeprom().hex() for s in bus})
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps({"servos": images}))
        tmp.replace(path)

    def _load_state(self, path: Path) -> None:
        try:
            images = json.loads(path.read_text())["servos"]
            saved = {int(k): bytes.fromhex(v) for k, v in images.items()}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"simulator state file {path} is unreadable ({exc}); delete it to start fresh") from exc

        def restore(bus: ServoBus, now: float) -> None:
            for servo in bus:
                if servo.servo_id in saved:
                    servo.restore_saved(saved[servo.servo_id], now)

        self.bus.inspect(restore)

    @property
    def port(self) -> str:
        return self.bus.port

    def set_latency_ms(self, latency_ms: float) -> None:
        self.bus.set_latency_ms(latency_ms)

    # -- read-back ------------------------------------------------------------------------

    def positions(self) -> dict[str, int]:
        """``Present_Position`` of every motor in raw ticks (what ``normalize=False`` reads)."""
        return self._per_motor(lambda servo, now: servo.present_position(now))

    def goal_positions(self) -> dict[str, int]:
        return self._per_motor(lambda servo, now: _advanced(servo, now).get("Goal_Position"))

    def register(self, motor: str, register: str) -> int:
        """Any register by its LeRobot name, sign-decoded."""
        return self._per_motor(lambda servo, now: _advanced(servo, now).get(register), [motor])[
            motor
        ]

    def torque_enabled(self) -> dict[str, bool]:
        return self._per_motor(lambda servo, _now: servo.torque_on())

    def joint_angles(self) -> dict[str, float]:
        """Every motor in degrees around the middle of its range (LeRobot's DEGREES rule)."""
        return self._per_motor(lambda servo, now: _degrees(servo, now))

    def normalized_positions(self) -> dict[str, float]:
        """What ``sync_read("Present_Position")`` returns, per each motor's norm mode."""

        def normalize(servo: Servo, now: float) -> float:
            spec = self._spec_by_id(servo.servo_id)
            entry = self.calibration.get(spec.name)
            drive = bool(entry and entry.drive_mode)
            return _normalize(servo, now, spec.norm_mode, drive)

        return self._per_motor(normalize)

    def is_moving(self) -> bool:
        return any(
            self._per_motor(lambda servo, now: _advanced(servo, now).get("Moving") == 1).values()
        )

    # -- manipulation and faults -------------------------------------------------------------

    def move_by_hand(self, motor: str, present_position: int) -> None:
        """Put a joint where ``Present_Position`` reads ``present_position`` (a limp arm moved by hand)."""

        def move(servo: Servo, now: float) -> None:
            servo.move_by_hand(present_position + servo.homing_offset(), now)

        self._per_motor(move, [motor])

    def unplug(self, motor: str) -> None:
        """The servo's cable is out: it neither hears nor answers."""
        self._update_faults(motor, unplugged=True)

    def plug(self, motor: str) -> None:
        self._update_faults(motor, unplugged=False)

    def corrupt_replies(
        self, motor: str, enabled: bool = True, *, count: int | None = None
    ) -> None:
        """This servo's replies carry a wrong checksum: all of them, or only the next ``count``."""
        if count is None:
            self._update_faults(motor, corrupt_checksum=enabled)
        else:
            self._update_faults(motor, corrupt_next=count)

    def drop_replies(self, motor: str, count: int = 1) -> None:
        """Lose this servo's next ``count`` replies (it still obeys the requests)."""
        self._update_faults(motor, drop_next=count)

    def send_stale_acks(self, motor: str, count: int = 1) -> None:
        """Put a late write acknowledgement (an empty status packet) before this servo's next ``count`` replies.

        It is what a loaded host's bus delivers when a write's reply came after its
        writer gave up: the next read's first answer, carrying no data.
        """
        self._update_faults(motor, stale_ack_next=count)

    def set_error_bits(self, motor: str, bits: int) -> None:
        """ERR byte of every status packet, e.g. ``ErrorBit.OVERHEAT``."""
        self._update_faults(motor, error_bits=bits)

    def overload(self, motor: str, enabled: bool = True) -> None:
        """Raise (or clear) the overload bit in this servo's status packets."""
        self.set_error_bits(motor, ErrorBit.OVERLOAD if enabled else 0)

    def block(self, motor: str, blocked: bool = True) -> None:
        """Put an obstacle in this joint's way: it pushes (load rises) but does not move."""
        self._update_faults(motor, blocked=blocked)

    def clear_faults(self, motor: str | None = None) -> None:
        for name in [motor] if motor else list(self.motors):
            self.bus.set_faults(self.motors[name].id, ServoFaults())

    def power_cycle(self) -> None:
        self.bus.power_cycle()

    # -- helpers ----------------------------------------------------------------------------

    def _spec_by_id(self, servo_id: int) -> MotorSpec:
        for spec in self.motors.values():
            if spec.id == servo_id:
                return spec
        raise KeyError(f"no motor with id {servo_id}")

    def _update_faults(self, motor: str, **changes: Any) -> None:
        servo_id = self._spec(motor).id

        def update(bus: ServoBus, _now: float) -> None:
            servo = bus.servo(servo_id)
            if servo is None:
                raise KeyError(f"servo {servo_id} ({motor}) is not on the bus")
            current = servo.faults
            servo.set_faults(replace(current, **changes))

        self.bus.inspect(update)

    def _spec(self, motor: str) -> MotorSpec:
        try:
            return self.motors[motor]
        except KeyError:
            raise KeyError(f"unknown motor {motor!r}; this arm has {list(self.motors)}") from None

    def _per_motor(
        self, fn: Callable[[Servo, float], T], names: Sequence[str] | None = None
    ) -> dict[str, T]:
        """Apply ``fn`` to the named servos (default: all) under the bus lock."""
        specs = [self._spec(n) for n in (names or list(self.motors))]

        def collect(bus: ServoBus, now: float) -> dict[str, T]:
            out: dict[str, T] = {}
            for spec in specs:
                servo = bus.servo(spec.id)
                if servo is None:
                    raise KeyError(
                        f"servo {spec.id} ({spec.name}) is not on the bus (id rewritten?)"
                    )
                out[spec.name] = fn(servo, now)
            return out

        return self.bus.inspect(collect)


def _advanced(servo: Servo, now: float) -> Servo:
    servo.advance(now)
    return servo


def _degrees(servo: Servo, now: float) -> float:
    low, high = servo.limits()
    return (servo.present_position(now) - (low + high) / 2) * 360 / _MAX_RES


def _normalize(servo: Servo, now: float, mode: str, drive: bool) -> float:
    """LeRobot's ``_normalize``: DEGREES ignores drive mode, the RANGE modes clamp and honour it."""
    if mode == DEGREES:
        return _degrees(servo, now)
    low, high = servo.limits()
    raw = max(low, min(high, servo.present_position(now)))
    fraction = (raw - low) / (high - low) if high > low else 0.0
    if mode == RANGE_0_100:
        return 100 - fraction * 100 if drive else fraction * 100
    value = fraction * 200 - 100
    return -value if drive else value
