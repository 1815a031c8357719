"""Child processes, free ports and polling: the plumbing every test-bed service shares.

A service is a real process started by us, logging to a file in its temp dir, and
stopped by us (SIGTERM, then SIGKILL). Nothing here knows what the process is.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from tests.testbed.errors import TestbedSetupError


def progress(message: str) -> None:
    """One progress line on stderr (the pytest plugin lifts output capture while services start)."""
    print(f"[testbed] {message}", file=sys.stderr, flush=True)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (bind port 0, read, close)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def require_tool(name: str, path: Path | None = None) -> str:
    """Absolute path of a tool (on PATH, or at ``path``), or a setup error."""
    if path is not None:
        if path.is_file() and os.access(path, os.X_OK):
            return str(path)
        raise TestbedSetupError(f"{name} not found at {path}")
    found = shutil.which(name)
    if found is None:
        raise TestbedSetupError(f"{name} is not installed (not on PATH)")
    return found


def wait_until(
    check: Callable[[], bool], *, timeout: float, what: str, interval: float = 0.2,
    alive: Callable[[], None] | None = None,
) -> None:
    """Poll ``check`` until true; ``alive`` raises early if the process behind it died."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if alive is not None:
            alive()
        try:
            if check():
                return
        except OSError:
            pass
        time.sleep(interval)
    raise TimeoutError(f"timed out after {timeout:.0f} s waiting for {what}")


class ManagedProcess:
    """One child process with its log file; ``stop()`` is safe to call twice."""

    def __init__(self, name: str, argv: Sequence[str], log_path: Path,
                 env: dict[str, str] | None = None) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_path
        self._log = open(log_path, "ab")  # noqa: SIM115 - lives as long as the process
        self.proc = subprocess.Popen(
            self.argv, stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env=env, start_new_session=True,  # Ctrl-C in `armnet dev up` reaches us, not them
        )

    def log_tail(self, lines: int = 30) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def ensure_running(self) -> None:
        code = self.proc.poll()
        if code is not None:
            raise RuntimeError(
                f"{self.name} exited with code {code}; last log lines ({self.log_path}):\n"
                f"{self.log_tail()}"
            )

    def stop(self, timeout: float = 10.0) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=timeout)
        self._log.close()
