"""Decoding a container log file in the CRI / Podman ``k8s-file`` format: pure, no I/O.

Each record is one line of the file::

    <RFC3339Nano timestamp> <stdout|stderr> <P|F> <content>

``P`` marks a piece of a line the engine cut (conmon writes at most its buffer
at once, and output not yet ended by a newline); the pieces up to the next ``F``
record of the same stream join into one line. The launcher reads the file the
engine writes instead of following the log through the Docker API, which is
slow and, with Podman 4.3, skips stretches of an exit burst (see
``container.ContainerJob``). The file is read while it grows, so the last line
of a read may be torn: it is kept until the rest arrives.
"""

from __future__ import annotations

from dataclasses import dataclass

STREAMS = (b"stdout", b"stderr")


class NotCriLog(ValueError):
    """A line of the file is not a CRI log record: the file is in another format."""


@dataclass(frozen=True)
class CriRecord:
    stream: bytes
    partial: bool
    content: bytes


def parse_record(line: bytes) -> CriRecord:
    """One record (without its newline), or :class:`NotCriLog`."""
    parts = line.split(b" ", 3)
    if len(parts) == 3:
        parts.append(b"")  # an empty F record may lose its separator
    if len(parts) != 4 or parts[1] not in STREAMS or parts[2] not in (b"P", b"F") or b"T" not in parts[0]:
        raise NotCriLog(f"not a CRI log record: {line[:80]!r}")
    return CriRecord(stream=parts[1], partial=parts[2] == b"P", content=parts[3])


class CriStreamDecoder:
    """One stream's output (``stdout`` or ``stderr``) from the file's bytes, in file order.

    ``feed`` takes the bytes as they are read and returns the complete output
    lines of the stream (newline-terminated, pieces joined); ``finish`` returns
    what is left once the file is read to its end for good: a last line without
    its newline, or a torn record.
    """

    def __init__(self, stream: str) -> None:
        if stream.encode() not in STREAMS:
            raise ValueError(f"stream must be stdout or stderr, not {stream!r}")
        self._stream = stream.encode()
        self._torn = b""
        self._pieces: list[bytes] = []

    def feed(self, data: bytes) -> bytes:
        records = (self._torn + data).split(b"\n")
        self._torn = records.pop()
        out: list[bytes] = []
        for line in records:
            self._take(parse_record(line), out)
        return b"".join(out)

    def finish(self) -> bytes:
        """The rest, once the writer is gone: a torn last record still counts (as a piece)."""
        out: list[bytes] = []
        if self._torn:
            torn, self._torn = self._torn, b""
            try:
                record = parse_record(torn)
            except NotCriLog:
                record = None  # cut inside its header: there is no content to recover
            if record is not None and record.stream == self._stream:
                self._pieces.append(record.content)
        if self._pieces:
            out.append(b"".join(self._pieces))
            self._pieces = []
        return b"".join(out)

    def _take(self, record: CriRecord, out: list[bytes]) -> None:
        if record.stream != self._stream:
            return
        if record.partial:
            self._pieces.append(record.content)
            return
        if self._pieces:
            self._pieces.append(record.content)
            out.append(b"".join(self._pieces))
            self._pieces = []
        else:
            out.append(record.content)
        out.append(b"\n")
