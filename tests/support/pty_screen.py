"""What a terminal shows a process run on a pty: for the tests of ``armnet teleop``'s screen."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable


class Screen:
    """Everything the process writes to the pty, drained in a thread so it never blocks on output."""

    def __init__(self, master: int) -> None:
        self.master, self.text = master, b""
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self) -> None:
        while True:
            try:
                chunk = os.read(self.master, 4096)
            except OSError:
                return
            if not chunk:
                return
            self.text += chunk

    def wait_for(self, seen: Callable[[bytes], bool], what: str, timeout: float = 20) -> None:
        deadline = time.monotonic() + timeout
        while not seen(self.text):
            assert time.monotonic() < deadline, f"{what} not on screen: {self.text[-1500:]!r}"
            time.sleep(0.05)
