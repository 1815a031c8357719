"""The bus a job gets: LeRobot's real ``FeetechMotorsBus`` whose every register write passes the policy.

Why at ``_write``/``_sync_write``: every public write path of the bus —
``write``, ``sync_write``, ``write_calibration``, ``enable/disable_torque``,
``configure_motors``, ``disconnect`` — ends in these two methods, and a job
cannot reach them (private names are refused). Deciding there, by register
address and servo id, covers every path LeRobot has or will add, with the
cell's motor table (never the job's names).

This module owns the subclass and its small changes to LeRobot's behaviour:
torque on/off leave ``Lock`` alone (the EEPROM stays locked), a disconnect with torque off reads the torque back
and records whether it is really off, and before a job's first write to a register the
connector restores later (``restore``), the servo's values go into the arm's ledger.
The decisions live in ``registers``.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NoReturn

from .block_read import read_block, read_register
from .calibration_check import CALIBRATION_REGISTERS as CALIBRATION_ORDER
from .calibration_check import calibration_mismatches, read_servo_calibration
from .errors import RequestError
from .identity import CellMotor
from .interlock import Interlock
from .registers import is_goal_register, is_restored, needs_current_value, write_refusal
from .reply_window import LATE_REPLY_WAIT_S
from .report import SafetyRecorder
from .restore import READ_RETRIES, RegisterLedger, RestoreBlock, restore_block
from .retry import retry_lost_replies

log = logging.getLogger(__name__)

#: How long ``record_ranges_of_motion`` waits at most for the operator to end it.
RANGE_RECORDING_MAX_S = 300.0
#: How often it reads the positions while the operator moves the joints.
RANGE_RECORDING_POLL_S = 0.05


def _nothing() -> None:
    return None


def _never_ends(_timeout_s: float) -> bool:
    time.sleep(_timeout_s)
    return False


#: Registers a calibration job (``allowCalibrationJobs``) may also write.
CALIBRATION_REGISTERS = frozenset({"Homing_Offset", "Min_Position_Limit", "Max_Position_Limit", "Lock"})


@dataclass(frozen=True)
class BusPolicy:
    """What the policed bus needs to decide a write: the cell's facts and the job's interlock."""

    arm: str
    motors_by_id: Mapping[int, tuple[str, CellMotor]]
    interlock: Interlock
    recorder: SafetyRecorder
    bounds: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    allow_calibration: bool = False
    #: The cell's calibration per servo id: (Homing_Offset, Min_Position_Limit, Max_Position_Limit).
    calibration: Mapping[int, tuple[int, int, int]] = field(default_factory=dict)
    #: ``record_ranges_of_motion``'s end signal from the operator inputs (a reset
    #: confirmation or a stop): waits up to the given seconds, True when the operator ends it.
    end_recording: Callable[[float], bool] = _never_ends
    recording_max_s: float = RANGE_RECORDING_MAX_S
    #: Called once per servo reply the connector's own reads lost and asked again (a metric).
    on_lost_reply: Callable[[], None] = _nothing
    #: The arm's values as the job found them, shared by every bus of the job on the arm (``restore``).
    ledger: RegisterLedger = field(default_factory=RegisterLedger)
    #: Per register address: the servo ids whose register there is a goal (``is_goal_register``).
    #: Filled on first use; the cell's motor table and the control tables never change.
    _goal_ids: dict[int, frozenset[int]] = field(default_factory=dict, init=False, compare=False, repr=False)

    def check_all(self, register_at: Any, address: int, ids_values: Mapping[int, Any]) -> None:
        """``check`` for each servo of a sync write (which never needs the value a servo holds).

        The usual control-loop write, goals while the interlock is clear, is decided by
        one lookup: each servo's register at ``address`` is its goal, which this policy
        allows (the motion guard has already checked the values against the cell's limits).
        Anything else goes through ``check`` servo by servo.
        """
        if not self.interlock.tripped:
            goal_ids = self._goal_ids.get(address)
            if goal_ids is None:
                goal_ids = self._goal_ids[address] = frozenset(
                    motor_id for motor_id, (_name, motor) in self.motors_by_id.items()
                    if is_goal_register(motor.model, register_at(motor.model, address))
                )
            if goal_ids.issuperset(ids_values):
                return
        for motor_id, value in ids_values.items():
            self.check(register_at, address, motor_id, int(value), _nothing)

    def check(self, register_at: Any, address: int, motor_id: int, value: int, read_current: Any) -> None:
        """Raise ``RequestError("NotAllowed")`` unless writing ``value`` at ``address`` of ``motor_id`` is allowed."""
        entry = self.motors_by_id.get(motor_id)
        if entry is None:
            self._refuse(None, f"servo id {motor_id} is not a motor of this cell; nothing was written")
        name, motor = entry
        register = register_at(motor.model, address)
        if register is None:
            self._refuse(name, f"address {address} of motor {name!r} is not a register of a {motor.model}")
        held = self.interlock.tripped
        if self.allow_calibration and register in CALIBRATION_REGISTERS and not held:
            return
        current = read_current() if needs_current_value(motor.model, register) and not held else None
        why = write_refusal(
            motor.model, register, name, value, interlock_held=held, bounds=self.bounds, current=current
        )
        if why is None:
            return
        refusal = self.interlock.refusal() if held else None
        if refusal is not None:
            # The interlock is the reason, whichever path the write took: a job in its grace
            # window is told so (ShuttingDown), as a motion request tripped at the same moment is.
            error_type, message = refusal
            self._refuse(name, f"{why}. {message}", error_type)
        self._refuse(name, why)

    def _refuse(self, motor: str | None, why: str, error_type: str = "NotAllowed") -> NoReturn:
        self.recorder.record_refusal("register", motor, why, tripped=False, arm=self.arm)
        raise RequestError(error_type, why)


@functools.cache
def policed_bus_class() -> type:
    """The subclass, built on first use (LeRobot is imported lazily: the connector starts without it)."""
    from lerobot.motors.feetech import FeetechMotorsBus

    if FeetechMotorsBus.__module__.startswith("armnet_runtime"):
        # The job's import swap, in the process that must drive the real bus.
        raise RuntimeError(
            "the connector found LeRobot's FeetechMotorsBus replaced by armnet's remote proxy: "
            "ARMNET_LEROBOT_TOOLS=remote is set in its environment, and it belongs to job containers only. "
            "Start the connector without it"
        )

    class PolicedFeetechBus(FeetechMotorsBus):  # type: ignore[misc]  # LeRobot is untyped
        """A ``FeetechMotorsBus`` that refuses register writes outside the cell's policy."""

        def __init__(self, *args: Any, armnet_policy: BusPolicy, **kwargs: Any) -> None:
            self._armnet_policy = armnet_policy
            super().__init__(*args, **kwargs)
            self._armnet_registers = {
                model: {addr: name for name, (addr, _length) in reversed(list(table.items()))}
                for model, table in self.model_ctrl_table.items()
            }
            models = {motor.model for _name, motor in armnet_policy.motors_by_id.values()}
            self._armnet_blocks: dict[str, RestoreBlock] = {
                model: restore_block(model, self.model_ctrl_table[model], self.model_encoding_table.get(model, {}))
                for model in models if model in self.model_ctrl_table
            }
            #: Addresses where some model of the cell keeps a restored register: one set lookup per write.
            self._armnet_restored_at = frozenset(
                self.model_ctrl_table[model][name][0] for model, block in self._armnet_blocks.items()
                for name in block.fields
            )

        def _register_at(self, model: str, address: int) -> str | None:
            return self._armnet_registers.get(model, {}).get(address)

        def _write(self, addr: int, length: int, motor_id: int, value: int, **kwargs: Any) -> Any:
            def current() -> int:
                # Not LeRobot's ``_read``: its 1- or 2-byte answer can be a late write
                # acknowledgement's checksum byte, and a legitimate write would be refused.
                held = read_register(self.packet_handler, self.port_handler, motor_id, addr, length,
                                     retries=READ_RETRIES)
                if held is None:
                    raise ConnectionError(
                        f"servo {motor_id} did not answer the read of the value this write would replace; "
                        "nothing was written. Retry"
                    )
                return held

            self._armnet_policy.check(self._register_at, addr, motor_id, int(value), current)
            if addr in self._armnet_restored_at:
                self._armnet_note_restored(addr, (motor_id,))
            return super()._write(addr, length, motor_id, value, **kwargs)

        def _sync_write(self, addr: int, length: int, ids_values: dict[int, int], *args: Any, **kwargs: Any) -> Any:
            self._armnet_policy.check_all(self._register_at, addr, ids_values)
            if addr in self._armnet_restored_at:
                self._armnet_note_restored(addr, tuple(ids_values))
            return super()._sync_write(addr, length, ids_values, *args, **kwargs)

        def _armnet_note_restored(self, addr: int, motor_ids: tuple[int, ...]) -> None:
            """Before the write goes out: each servo's values as the job found them, and the register as touched.

            The snapshot is read once per servo, before the job's first write to any of
            its restored registers, so a connection that dies right after the write still
            leaves the connector what to put back. A servo whose snapshot cannot be read
            is not written: the connector could not put the value back.
            """
            ledger = self._armnet_policy.ledger
            for motor_id in motor_ids:
                name, motor = self._armnet_policy.motors_by_id[motor_id]  # the policy check passed: a cell motor
                register = self._register_at(motor.model, addr)
                if not is_restored(motor.model, register):
                    continue
                if not ledger.has_snapshot(motor_id):
                    block = self._armnet_blocks[motor.model]
                    data = read_block(self.packet_handler, self.port_handler, motor_id, block.start, block.length,
                                      retries=READ_RETRIES, ignore_status_bits=True)
                    if data is None:
                        raise ConnectionError(
                            f"motor {name!r} did not answer the read of the values this write would replace, so the "
                            "connector could not put them back at the end of the job; nothing was written. Retry"
                        )
                    ledger.keep_snapshot(motor_id, block.decode(data))
                ledger.touch(motor_id, str(register))

        # Torque on/off without Lock: the cell keeps its servos' EEPROM locked (a calibration
        # job that wants its writes saved writes Lock=0 itself; the connector relocks at the end).
        def disable_torque(self, motors: Any = None, num_retry: int = 0) -> None:
            for motor in self._get_motors_list(motors):
                self.write("Torque_Enable", motor, 0, num_retry=num_retry)

        def _disable_torque(self, motor: int, model: str, num_retry: int = 0) -> None:
            addr, _length = self.model_ctrl_table[model]["Torque_Enable"]
            self._write(addr, 1, motor, 0, num_retry=num_retry)

        def enable_torque(self, motors: Any = None, num_retry: int = 0) -> None:
            for motor in self._get_motors_list(motors):
                self.write("Torque_Enable", motor, 1, num_retry=num_retry)

        # Every cell: the connector checks the servos' EEPROM against the cell's calibration
        # when the bus connects (a servo changed outside armnet is reported, never "fixed").
        # A calibration job (allowCalibrationJobs) may rewrite it: restored when the bus lets go.
        def connect(self, handshake: bool = True) -> None:
            super().connect(handshake)
            if self._armnet_policy.calibration:
                self._armnet_check_calibration("start")

        def record_ranges_of_motion(
            self, motors: Any = None, display_values: bool = True
        ) -> tuple[dict[str, Any], dict[str, Any]]:
            """LeRobot's range recording without the connector's terminal: no table printed, no Enter read.

            Why: LeRobot prints a live table and reads Enter from stdin; in the connector
            those are the sidecar's, not the operator's. Here the operator's inputs end it
            (a reset confirmation, or a stop), or ``recording_max_s`` passes; the ranges
            go back to the job as the call's value. ``display_values`` is accepted and
            ignored (the job prints what it gets). Same refusal as LeRobot when a joint
            did not move. Unlike LeRobot's, a poll that lost a servo reply is asked again:
            one late reply in minutes of polling must not throw the operator's work away.
            """
            del display_values
            policy = self._armnet_policy
            names = self._get_motors_list(motors)
            mins = dict(self._armnet_raw_positions(names))
            maxes = dict(mins)
            deadline = time.monotonic() + policy.recording_max_s
            ended = False
            while not ended:
                ended = policy.end_recording(RANGE_RECORDING_POLL_S) or time.monotonic() >= deadline
                positions = self._armnet_raw_positions(names)
                mins = {m: min(positions[m], v) for m, v in mins.items()}
                maxes = {m: max(positions[m], v) for m, v in maxes.items()}
            unmoved = [m for m in names if mins[m] == maxes[m]]
            if unmoved:
                raise ValueError(f"Some motors have the same min and max values: {unmoved}; move every joint through its range")
            return mins, maxes

        def _armnet_raw_positions(self, names: list[str]) -> dict[str, Any]:
            """The motors' raw positions; a lost reply is asked again (``retry``), as a job's own read is."""
            return retry_lost_replies(
                self, "record_ranges_of_motion's sync_read",
                lambda: self.sync_read("Present_Position", names, normalize=False),
                on_retry=self._armnet_policy.on_lost_reply,
            )

        def _armnet_eeprom(self) -> dict[int, tuple[int, int, int] | None]:
            """Each servo's calibration registers (None: silent, a mismatch), one block read per servo."""
            return {motor.id: read_servo_calibration(self.packet_handler, self.port_handler, motor.id)
                    for motor in self.motors.values()}

        def _armnet_check_calibration(self, when: str) -> bool:
            policy = self._armnet_policy
            found = calibration_mismatches(policy.calibration, self._armnet_eeprom())
            policy.recorder.record_calibration_check(policy.arm, [f"{when}: {m.describe()}" for m in found])
            return not found

        def _armnet_restore_calibration(self) -> None:
            """Write the cell's calibration back (unlocked, so it is saved), then lock and verify.

            The connector's own writes: they bypass the job's policy (the interlock holds
            at shutdown, and these are exactly the cell's values).
            """
            policy = self._armnet_policy
            for motor in self.motors.values():
                wanted = policy.calibration.get(motor.id)
                if wanted is None:
                    continue
                table = self.model_ctrl_table[motor.model]
                lock_addr, lock_length = table["Lock"]
                super()._write(lock_addr, lock_length, motor.id, 0, num_retry=2)
                for register, value in zip(CALIBRATION_ORDER, wanted, strict=True):
                    addr, length = table[register]
                    encoded = self._encode_sign(register, {motor.id: value})[motor.id]
                    super()._write(addr, length, motor.id, encoded, num_retry=2)
                super()._write(lock_addr, lock_length, motor.id, 1, num_retry=2)
            if self._armnet_check_calibration("end"):
                policy.recorder.record_calibration(policy.arm, "end: the cell's calibration is in place")

        def _armnet_drop_late_replies(self) -> None:
            """After a lost reply, let it land and drop it, so the next user of the line never reads it."""
            time.sleep(LATE_REPLY_WAIT_S)
            try:
                self.port_handler.ser.reset_input_buffer()
            except Exception as exc:  # noqa: BLE001 — the port is closed next anyway
                log.debug("could not drop late replies: %s", exc)

        def disconnect(self, disable_torque: bool = True) -> None:
            if self._armnet_policy.allow_calibration and self.is_connected:
                try:
                    self._armnet_restore_calibration()
                except Exception as exc:  # noqa: BLE001 — reported; the port must still close
                    self._armnet_policy.recorder.record_calibration(
                        self._armnet_policy.arm, f"end: restoring the cell's calibration failed: {exc}"
                    )
            if disable_torque and self.is_connected:
                self.port_handler.clearPort()
                self.port_handler.is_using = False
                confirmed = False
                try:
                    self.disable_torque(num_retry=5)
                    torque = self.sync_read("Torque_Enable", normalize=False, num_retry=3)
                    confirmed = all(int(v) == 0 for v in torque.values())
                except Exception as exc:  # noqa: BLE001 — recorded as unconfirmed; the port must still close
                    log.warning("torque off could not be confirmed on %s: %s", self._armnet_policy.arm, exc)
                    self._armnet_drop_late_replies()
                self._armnet_policy.recorder.record_torque_off(self._armnet_policy.arm, confirmed)
            super().disconnect(disable_torque=False)

    # LeRobot's messages name the class ("FeetechMotorsBus motor check failed ..."): a job
    # sees the same text as on a bare arm.
    PolicedFeetechBus.__name__ = PolicedFeetechBus.__qualname__ = FeetechMotorsBus.__name__
    return PolicedFeetechBus
