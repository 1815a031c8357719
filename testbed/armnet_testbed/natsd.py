"""A real ``nats-server -js`` on a free loopback port with a temporary JetStream store.

``restart()`` keeps the port and the store, so tests can prove that JetStream state
and durable consumers survive a server restart and a client reconnect.
"""

from __future__ import annotations

import shutil
import socket
import tempfile
import time
from pathlib import Path

from armnet_testbed.procs import ManagedProcess, free_port, progress, require_tool, wait_until


class NatsServer:
    """nats-server with JetStream; ``url`` is ``nats://127.0.0.1:<port>``."""

    def __init__(self, workdir: Path | None = None) -> None:
        self._owns_workdir = workdir is None
        self.workdir = workdir or Path(tempfile.mkdtemp(prefix="armnet-nats-"))
        self.port = free_port()
        self.url = f"nats://127.0.0.1:{self.port}"
        self.store_dir = self.workdir / "jetstream"
        self._proc: ManagedProcess | None = None

    def start(self) -> NatsServer:
        binary = require_tool("nats-server")
        started = time.monotonic()
        self._proc = ManagedProcess("nats-server", [
            binary, "-js", "-a", "127.0.0.1", "-p", str(self.port), "-sd", str(self.store_dir),
            "-n", "armnet-testbed",
        ], self.workdir / "nats-server.log")
        proc = self._proc
        wait_until(self._accepts_clients, timeout=20, what=f"nats-server on {self.url}",
                   alive=proc.ensure_running)
        progress(f"nats-server ready at {self.url} in {time.monotonic() - started:.1f} s")
        return self

    def _accepts_clients(self) -> bool:
        # The server greets every TCP client with an INFO line once it is serving.
        with socket.create_connection(("127.0.0.1", self.port), timeout=1) as sock:
            return sock.recv(4).startswith(b"INFO")

    def restart(self) -> None:
        """Stop and start again on the same port with the same JetStream store."""
        if self._proc is not None:
            self._proc.stop()
        self.start()

    def stop(self) -> None:
        if self._proc is not None:
            self._proc.stop()
            self._proc = None
        if self._owns_workdir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> NatsServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
