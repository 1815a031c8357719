"""Feetech SCS/STS wire protocol: instruction frames in, status frames out.

This module owns the byte layout only. It never touches a file descriptor and
never knows what a register means, so the framing rules (resync on ``FF FF``,
checksum, split and coalesced writes) can be tested byte by byte.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
#: The SDK refuses packets longer than 250 bytes, so a larger LEN is line noise.
MAX_LENGTH_FIELD = 250


class Instr(IntEnum):
    """Instruction codes of the Feetech protocol (``scservo_def.py`` plus RESET)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    RESET = 0x06
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83


class ErrorBit(IntEnum):
    """Bits of the status packet's ERR byte, as ``getRxPacketError`` names them."""

    VOLTAGE = 0x01
    ANGLE = 0x02
    OVERHEAT = 0x04
    OVERELE = 0x08
    OVERLOAD = 0x20


def checksum(body: bytes) -> int:
    """Feetech checksum over everything between the header and the checksum byte."""
    return (~sum(body)) & 0xFF


@dataclass(frozen=True)
class Instruction:
    """One well-formed instruction frame addressed to ``servo_id`` (0xFE = broadcast)."""

    servo_id: int
    code: int
    params: bytes = b""

    def encode(self) -> bytes:
        """Bytes a host would send; used by tests to talk to the simulator."""
        body = bytes([self.servo_id, len(self.params) + 2, self.code]) + self.params
        return HEADER + body + bytes([checksum(body)])


def is_lone_sync_write(data: bytes) -> bool:
    """True when ``data`` is exactly one well-formed SYNC_WRITE frame to the broadcast id.

    No servo answers such a frame, and ``FrameParser`` (with nothing buffered)
    would return it whole: the simulator may apply it later, with its arrival
    time, as long as nothing else reaches the servos first.
    """
    return (
        len(data) >= 6
        and data[0] == 0xFF
        and data[1] == 0xFF
        and data[2] == BROADCAST_ID
        and data[3] <= MAX_LENGTH_FIELD
        and data[3] + 4 == len(data)
        and data[4] == Instr.SYNC_WRITE
        and checksum(data[2:-1]) == data[-1]
    )


def encode_status(servo_id: int, error: int, data: bytes = b"", *, corrupt: bool = False) -> bytes:
    """A status packet; ``corrupt`` flips the checksum to simulate line noise."""
    body = bytes([servo_id, len(data) + 2, error & 0xFF]) + data
    chk = checksum(body)
    if corrupt:
        chk ^= 0xFF
    return HEADER + body + bytes([chk])


class FrameParser:
    """Incremental parser for the host-to-servo byte stream.

    A real servo decodes whatever arrives on the wire, so this parser never raises:
    bytes before a header are skipped, a frame with a bad checksum or an impossible
    length is dropped and the scan resumes right after its header (a valid frame
    may start inside it). An unfinished frame is abandoned when, after a gap of
    more than ``stale_after_s``, the next chunk starts with a fresh header: that
    is the host retrying after its timeout, and the retry must not be swallowed
    as the tail of a truncated request. A late chunk that does not start with a
    header is still taken as the continuation (the reader may simply have been
    descheduled between two halves of one write).
    """

    def __init__(self, stale_after_s: float = 0.02) -> None:
        self._buf = bytearray()
        self._last_feed: float | None = None
        self._stale_after_s = stale_after_s
        self.dropped_frames = 0

    @property
    def idle(self) -> bool:
        """Nothing buffered: the next chunk starts a frame of its own."""
        return not self._buf

    def feed(self, data: bytes, now: float = 0.0) -> list[Instruction]:
        """Add bytes received at time ``now``; return every frame now complete."""
        if (
            self._buf
            and self._last_feed is not None
            and now - self._last_feed > self._stale_after_s
            and data.startswith(HEADER)
        ):
            self._buf.clear()
            self.dropped_frames += 1
        self._buf += data
        frames: list[Instruction] = []
        while True:
            frame, complete = self._next_frame()
            if frame is not None:
                frames.append(frame)
            if not complete:
                break
        self._last_feed = now if self._buf else None
        return frames

    def _next_frame(self) -> tuple[Instruction | None, bool]:
        """Consume at most one frame; the flag says whether to keep scanning."""
        start = self._buf.find(HEADER)
        if start < 0:
            # Keep a trailing 0xFF: it may be the first half of the next header.
            keep = 1 if self._buf.endswith(b"\xff") else 0
            del self._buf[: len(self._buf) - keep]
            return None, False
        del self._buf[:start]
        if len(self._buf) < 4:
            return None, False
        servo_id, length = self._buf[2], self._buf[3]
        if servo_id == 0xFF or length < 2 or length > MAX_LENGTH_FIELD:
            del self._buf[:1]
            return None, True
        total = length + 4
        if len(self._buf) < total:
            return None, False
        frame = bytes(self._buf[:total])
        if checksum(frame[2:-1]) != frame[-1]:
            del self._buf[:2]
            self.dropped_frames += 1
            return None, True
        del self._buf[:total]
        return Instruction(servo_id=servo_id, code=frame[4], params=frame[5:-1]), True
