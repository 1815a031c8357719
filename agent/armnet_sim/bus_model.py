"""A multi-drop servo bus: instruction frames in, the bytes the servos answer out.

This is the protocol brain of the simulator and it is pure (time is an
argument). Each servo answers only for itself, the way a half-duplex TTL bus
behaves: unknown or unplugged ids stay silent, SYNC_READ answers come back in
request order, broadcast writes and SYNC_WRITE get no answer.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from .protocol import BROADCAST_ID, Instr, Instruction, encode_status
from .servo import Servo


class ServoBus:
    """The servos sharing one serial line."""

    def __init__(self, servos: Iterable[Servo]) -> None:
        self._servos = list(servos)
        #: The host's line speed (bit/s) when known: a servo set to another rate
        #: (its Baud_Rate register) sees only noise, so it neither obeys nor answers.
        self.line_baud: int | None = None

    def __iter__(self) -> Iterator[Servo]:
        return iter(self._servos)

    def servo(self, servo_id: int) -> Servo | None:
        """The servo answering to ``servo_id`` now (ids can be rewritten over the wire)."""
        for servo in self._servos:
            if servo.servo_id == servo_id:
                return servo
        return None

    def _hears(self, servo: Servo) -> bool:
        return not servo.faults.unplugged and (self.line_baud is None or servo.baudrate() == self.line_baud)

    def _reachable(self, servo_id: int) -> list[Servo]:
        if servo_id == BROADCAST_ID:
            found = [s for s in self._servos if self._hears(s)]
            return sorted(found, key=lambda s: s.servo_id)
        servo = self.servo(servo_id)
        return [servo] if servo is not None and self._hears(servo) else []

    def handle(self, instruction: Instruction, now: float) -> bytes:
        """Apply one instruction; return the concatenated status packets (maybe none)."""
        code, params = instruction.code, instruction.params
        targets = self._reachable(instruction.servo_id)
        unicast = instruction.servo_id != BROADCAST_ID
        if code == Instr.PING:
            return b"".join(_status(s, b"") for s in targets)
        if code == Instr.READ:
            if not unicast or len(params) != 2:
                return b""
            return b"".join(_status(s, s.read(params[0], params[1], now)) for s in targets)
        if code in (Instr.WRITE, Instr.REG_WRITE):
            if not params:
                return b""
            for servo in targets:
                if code == Instr.WRITE:
                    servo.write(params[0], params[1:], now)
                else:
                    servo.reg_write(params[0], params[1:])
            return self._acks(targets, unicast)
        if code == Instr.ACTION:
            for servo in targets:
                servo.action(now)
            return self._acks(targets, unicast)
        if code == Instr.RESET:
            for servo in targets:
                servo.factory_reset(now)
            return self._acks(targets, unicast)
        if code == Instr.SYNC_READ and not unicast:
            return self._sync_read(params, now)
        if code == Instr.SYNC_WRITE and not unicast:
            self._sync_write(params, now)
        return b""

    @staticmethod
    def _acks(targets: list[Servo], unicast: bool) -> bytes:
        if not unicast:
            return b""
        return b"".join(_status(s, b"") for s in targets if s.replies_to_writes())

    def _sync_read(self, params: bytes, now: float) -> bytes:
        if len(params) < 3:
            return b""
        address, length = params[0], params[1]
        replies = []
        for servo_id in params[2:]:
            for servo in self._reachable(servo_id):
                replies.append(_status(servo, servo.read(address, length, now)))
        return b"".join(replies)

    def _sync_write(self, params: bytes, now: float) -> None:
        if len(params) < 2:
            return
        address, length = params[0], params[1]
        records = params[2:]
        stride = length + 1
        for start in range(0, len(records) - stride + 1, stride):
            servo_id = records[start]
            for servo in self._reachable(servo_id):
                servo.write(address, records[start + 1 : start + stride], now)


def _status(servo: Servo, data: bytes) -> bytes:
    stale = encode_status(servo.servo_id, 0) if servo.take_stale_ack() else b""
    drop, corrupt = servo.take_reply_faults()
    if drop:
        return stale
    return stale + encode_status(servo.servo_id, servo.status_error(), data, corrupt=corrupt)
