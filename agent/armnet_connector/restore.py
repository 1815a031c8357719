"""Putting back the RAM registers a job tuned, when the job's bus lets go of the arm: the rules.

Why: a job may write some RAM registers within the cell's bounds (``Torque_Limit``,
``Acceleration``, ``Goal_Velocity``, ``Goal_Time``: ``registers.Rule.BOUNDED``). The
servo keeps them until it loses power, so without this the next tenant's arm would
run with this job's lowered torque limit or slow profile.

How: before a job's first write to such a register of a servo, the policed bus reads
the servo's whole block of restored registers (one read of a length no other read
asks for, ``block_read``) into the arm's ``RegisterLedger``, and marks the register
touched. When the job's last bus on the arm lets go (its ``disconnect``, its object
closed, its connection dropped, the connector's stop), the cell's own bus holds every
servo with torque on where it is (goal = present position, so nothing the restore
writes can move the arm toward a goal it had not reached), writes each touched
register back in ``registers.RESTORE_ORDER`` and reads the servos back.

This module owns the ledger and the pure decisions (where the registers sit, what
to write back, what the read-back says). It does no I/O: the restore on the cell's
bus is ``rest.restore_registers``, the device lock and the report ``cell``'s; what a
job may write is ``registers``'.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from .registers import RESTORE_ORDER, is_restored

#: Extra tries of a block read (each waits past the reply window first).
READ_RETRIES = 3
#: Write-and-read-back rounds before a register that does not read back as written is reported.
WRITE_ROUNDS = 3


@dataclass(frozen=True)
class RestoreBlock:
    """Where a model's restored registers sit: one contiguous run of its control table."""

    start: int
    length: int
    #: register -> (offset in the block, size in bytes, sign-magnitude bit or None)
    fields: Mapping[str, tuple[int, int, int | None]]

    def decode(self, data: Sequence[int]) -> dict[str, int]:
        """The registers' values as LeRobot's ``read(..., normalize=False)`` gives them (sign decoded)."""
        values = {}
        for name, (offset, size, sign_bit) in self.fields.items():
            raw = int.from_bytes(bytes(data[offset:offset + size]), "little")
            if sign_bit is not None and raw & (1 << sign_bit):
                raw = -(raw & ((1 << sign_bit) - 1))
            values[name] = raw
        return values


def restore_block(model: str, table: Mapping[str, tuple[int, int]], sign_bits: Mapping[str, int]) -> RestoreBlock:
    """The block of ``model``'s restored registers, from its control table (LeRobot's ``name: (address, size)``).

    On the STS3215: addresses 41 (Acceleration) to 49 (Torque_Limit's high byte), 9
    bytes, a length no LeRobot read asks for. Little-endian: the STS series' byte order.
    """
    names = [name for name in RESTORE_ORDER if name in table and is_restored(model, name)]
    if not names:
        return RestoreBlock(0, 0, {})
    start = min(table[name][0] for name in names)
    end = max(table[name][0] + table[name][1] for name in names)
    fields = {name: (table[name][0] - start, table[name][1], sign_bits.get(name)) for name in names}
    return RestoreBlock(start, end - start, fields)


class RegisterLedger:
    """One arm's values as the job found them: per servo id, its restored registers before the job's first write.

    Thread-safe: job connections write through it while the connector's release reads it.
    A snapshot is kept for the job's whole life (the values it found); a touched register
    stays pending until the connector read it back as restored.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._found: dict[int, dict[str, int]] = {}
        self._touched: dict[int, set[str]] = {}

    def has_snapshot(self, servo_id: int) -> bool:
        with self._lock:
            return servo_id in self._found

    def keep_snapshot(self, servo_id: int, values: Mapping[str, int]) -> None:
        """The servo's registers before the job's first write (a later snapshot never replaces it)."""
        with self._lock:
            self._found.setdefault(servo_id, dict(values))

    def touch(self, servo_id: int, register: str) -> None:
        """The job is about to write ``register`` of ``servo_id`` (its snapshot is kept already)."""
        with self._lock:
            self._touched.setdefault(servo_id, set()).add(register)

    def pending(self) -> dict[int, dict[str, int]]:
        """servo id -> register -> the value the job found, for every register it touched and not yet restored."""
        with self._lock:
            return {
                servo_id: {r: self._found[servo_id][r] for r in sorted(registers) if r in self._found.get(servo_id, {})}
                for servo_id, registers in self._touched.items() if registers
            }

    def settle(self, servo_id: int, register: str) -> None:
        """``register`` of ``servo_id`` reads back as the job found it: nothing left to restore there."""
        with self._lock:
            registers = self._touched.get(servo_id)
            if registers is not None:
                registers.discard(register)


@dataclass(frozen=True)
class Restored:
    """One register written back: what the job left (None: not readable before the restore) and what it holds now."""

    motor: str
    register: str
    found: int | None
    value: int


@dataclass(frozen=True)
class RestoreOutcome:
    """What one restore of an arm did: the registers written back and read back, and the ones that failed."""

    restored: tuple[Restored, ...] = ()
    #: One line per register (or per arm, when nothing could be written) that is not as the job found it.
    failures: tuple[str, ...] = ()
    #: (servo id, register) read back as the job found it: settled in the ledger.
    settled: tuple[tuple[int, str], ...] = ()


def restore_plan(
    pending: Mapping[int, Mapping[str, int]], held: Mapping[int, Mapping[str, int] | None]
) -> dict[str, dict[int, int]]:
    """Per register, in ``RESTORE_ORDER``: servo id -> the value to write back. Pure.

    Only registers that differ from what the job found; a job that put a value back
    itself leaves nothing to write. A servo that could not be read (``held`` None) is
    left out: it cannot be held in place first, so nothing is written to it.
    """
    plan: dict[str, dict[int, int]] = {}
    for register in RESTORE_ORDER:
        for servo_id in sorted(pending):
            original, now = pending[servo_id].get(register), held.get(servo_id)
            if original is not None and now is not None and now.get(register) != original:
                plan.setdefault(register, {})[servo_id] = original
    return plan


def judge_restore(
    pending: Mapping[int, Mapping[str, int]],
    before: Mapping[int, Mapping[str, int] | None],
    after: Mapping[int, Mapping[str, int] | None],
    names: Mapping[int, str],
) -> RestoreOutcome:
    """The outcome from the values read before and after the write-back. Pure.

    A register that read back as the job found it is settled (and listed as restored
    when the job had changed it); one that did not, or a servo that did not answer, is
    a failure naming the motor, the register and the values.
    """
    restored, failures, settled = [], [], []
    for register in RESTORE_ORDER:
        for servo_id in sorted(pending):
            original = pending[servo_id].get(register)
            if original is None:
                continue
            name = names.get(servo_id, f"servo {servo_id}")
            motor = f"{name} (id {servo_id})"
            was, now = before.get(servo_id), after.get(servo_id)
            if was is None:
                failures.append(f"{motor}: {register} was not written back to {original} (the value the job "
                                "found): the servo did not answer, so it could not be read and held first")
            elif now is None:
                failures.append(f"{motor}: {register} could not be read back after writing {original} (the "
                                "value the job found): the servo did not answer")
            elif now.get(register) != original:
                failures.append(f"{motor}: {register} is {now.get(register)} after the restore, not {original} "
                                "(the value the job found)")
            else:
                settled.append((servo_id, register))
                if was.get(register) != original:
                    restored.append(Restored(name, register, was.get(register), original))
    return RestoreOutcome(tuple(restored), tuple(failures), tuple(settled))


def servos_of(plan: Mapping[str, Mapping[int, int]]) -> list[int]:
    """The servo ids a plan writes to."""
    return sorted({servo_id for values in plan.values() for servo_id in values})
