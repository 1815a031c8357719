"""A bounded text tail: the last lines of a stream, capped in characters.

Results carry ``stdoutTail``/``stderrTail`` that must stay small (they end up
in etcd); full logs go to the log stream. Pure: no I/O.
"""

from __future__ import annotations

from collections import deque

DEFAULT_TAIL_CHARS = 16 * 1024


class BoundedTail:
    """Keeps the most recent lines whose total length fits in ``max_chars``.

    A single line longer than the cap is cut to its last ``max_chars``
    characters, so the newest output is always present.
    """

    def __init__(self, max_chars: int = DEFAULT_TAIL_CHARS) -> None:
        if max_chars <= 0:
            raise ValueError("max_chars must be positive")
        self._max = max_chars
        self._lines: deque[str] = deque()
        self._size = 0
        self.dropped_lines = 0

    def append(self, line: str) -> None:
        line = line if line.endswith("\n") else line + "\n"
        if len(line) > self._max:
            line = line[-self._max :]
        self._lines.append(line)
        self._size += len(line)
        while self._size > self._max:
            self._size -= len(self._lines.popleft())
            self.dropped_lines += 1

    def text(self) -> str:
        return "".join(self._lines)

    def __len__(self) -> int:
        return len(self._lines)
