"""Child processes, ports and polling: the plumbing every test-bed service shares.

A service is a real process started by us, logging to a file in its temp dir, and
stopped by us (SIGTERM, then SIGKILL). Nothing here knows what the process is.
"""

from __future__ import annotations

import fcntl
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from armnet_testbed.errors import TestbedSetupError


def progress(message: str) -> None:
    """One progress line on stderr (the pytest plugin lifts output capture while services start)."""
    print(f"[testbed] {message}", file=sys.stderr, flush=True)


#: Where test-bed processes claim ports: one lock file per port, held for the process's life.
PORT_CLAIMS = Path(tempfile.gettempdir()) / "armnet-testbed-ports"
#: How many ports below the kernel's ephemeral range the test beds draw from.
PORT_SPAN = 12_000
_claimed: list[int] = []  # open lock files: closing one would free its port for another process


def free_port() -> int:
    """A TCP port on 127.0.0.1 for a service this process is about to start, and no one else's.

    "Bind port 0, read it, close" handed the same port twice: to the second of two picks
    in a row (etcd's client and peer ports: "bind: address already in use"), to another
    test session starting a control plane at the same moment, or to any process's
    outgoing connection, which takes its local port from the same ephemeral range. So
    the port is drawn from below that range (no ``bind(0)`` or ``connect`` takes it), claimed
    with a lock file that this process holds until it exits (no other test-bed process
    takes it), and checked free to bind now.
    """
    low, _ = (int(v) for v in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    first = max(1024, low - PORT_SPAN)
    PORT_CLAIMS.mkdir(mode=0o1777, parents=True, exist_ok=True)
    span = low - first
    start = random.randrange(span)
    for offset in range(span):
        port = first + (start + offset) % span
        fd = os.open(PORT_CLAIMS / str(port), os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue  # another test-bed process holds it
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                os.close(fd)  # something outside the test beds listens there
                continue
        _claimed.append(fd)
        return port
    raise TestbedSetupError(f"no free port in {first}-{low - 1} on 127.0.0.1 (claims in {PORT_CLAIMS})")


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
                 env: dict[str, str] | None = None, cwd: Path | None = None) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_path
        self._log = open(log_path, "ab")  # noqa: SIM115 - lives as long as the process
        self.proc = subprocess.Popen(
            self.argv, stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env=env, cwd=cwd, start_new_session=True,  # Ctrl-C in `armnet dev up` reaches us, not them
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
