"""A run of one servo's registers in one read whose length no other read asks for.

Why: a Feetech status packet names its servo but not the register it answers, so a
late reply to one register read can pass for the next register's (every later value
shifted by one register; seen on a loaded host, and the SDK's own immediate retry
does it). A block read of a length no other read asks for can only be answered by a
late reply to an earlier try of the same read, with the same bytes; a reply of any
other length is no answer. Each try starts on an empty input and waits past the
reply window after a miss (``reply_window``).

This module owns that read (plain ``scservo_sdk`` calls, no LeRobot): the calibration
check reads the calibration block with it, the connector the block of the registers
it restores and the value an EEPROM write would replace (``read_register``). It never
writes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, TypeVar

from .reply_window import LATE_REPLY_WAIT_S

T = TypeVar("T")

#: The length of ``read_register``'s window. No other read of the bus asks for 3 bytes
#: (LeRobot's reads ask for 1 or 2, the telemetry block 8, the restore block 9, the
#: calibration block 24): a late write acknowledgement, or a late answer to another
#: register's read, cannot pass for its answer.
REGISTER_READ_LENGTH = 3

#: ``scservo_sdk``'s COMM_SUCCESS (the module is not imported here: the probe loads it lazily).
COMM_SUCCESS = 0


def read_block(
    packets: Any, handler: Any, motor_id: int, start: int, length: int, *, retries: int,
    ignore_status_bits: bool = False, deadline: float | None = None,
) -> list[int] | None:
    """The servo's ``length`` bytes from ``start``, or None when it stays silent (``retries`` more tries).

    ``ignore_status_bits``: a reply whose error byte reports the servo's state (overload,
    heat, voltage) still carries the bytes. ``deadline`` (``time.monotonic()``) ends the
    tries early. ``scservo_sdk`` skips replies from other servos itself, and raises
    IndexError on a truncated reply instead of reporting it.
    """
    def read() -> list[int] | None:
        try:
            data, result, error = packets.readTxRx(handler, motor_id, start, length)
        except (IndexError, OSError):
            return None
        if result == COMM_SUCCESS and (ignore_status_bits or not error) and len(data) == length:
            return [int(b) for b in data]
        return None

    return ask_until_answered(handler, read, 1 + retries, deadline=deadline)


def read_register(packets: Any, handler: Any, motor_id: int, address: int, size: int, *,
                  retries: int) -> int | None:
    """The raw unsigned value the servo holds in the ``size`` bytes at ``address``, or None when it stays silent.

    Read as the end of a ``REGISTER_READ_LENGTH``-byte window (from address 0 when the
    register sits lower), so the window never runs past the register into addresses a
    servo may not have. Little-endian: the STS series' byte order. A reply whose error
    byte reports the servo's state still carries the value.
    """
    if not 0 < size <= REGISTER_READ_LENGTH:
        raise ValueError(f"a register of {size} bytes does not fit a {REGISTER_READ_LENGTH}-byte read")
    start = max(0, address + size - REGISTER_READ_LENGTH)
    data = read_block(packets, handler, motor_id, start, REGISTER_READ_LENGTH, retries=retries,
                      ignore_status_bits=True)
    if data is None:
        return None
    return int.from_bytes(bytes(data[address - start:address - start + size]), "little")


def ask_until_answered(handler: Any, ask: Callable[[], T | None], tries: int, *,
                       deadline: float | None = None) -> T | None:
    """``ask()``'s first answer that is not None, over up to ``tries`` requests.

    Before each retry it waits past the reply window and drops everything waiting on the
    line: a reply that came after its request gave up is no answer, and must not be read
    as the answer to the next request. Every idle read of the bus goes through it (the
    agent's pings, the calibration and restore block reads), so a loaded host answers as
    LeRobot's reads do. ``deadline`` (``time.monotonic()``) ends the tries early.
    """
    for attempt in range(tries):
        if attempt:
            if deadline is not None and time.monotonic() + LATE_REPLY_WAIT_S >= deadline:
                return None
            time.sleep(LATE_REPLY_WAIT_S)
        handler.ser.reset_input_buffer()
        answer = ask()
        if answer is not None:
            return answer
    return None
