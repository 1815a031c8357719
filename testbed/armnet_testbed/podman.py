"""Podman's Docker-compatible API on a private unix socket, reached with ``docker``.

The service is ``podman system service --time=0 unix://<tmp>/podman.sock``: the same
engine and image store as the ``podman`` CLI (root), so the base image built by
scripts/setup.d/40-base-image.sh is visible. The API ignores containers.conf's
default ulimits, so every container must pass ``ULIMITS`` explicitly.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.procs import ManagedProcess, progress, require_tool, wait_until

# Below this VM's hard limits (nofile 20000, nproc 96365): runc cannot raise them.
ULIMIT_SPEC: tuple[tuple[str, int, int], ...] = (("nofile", 4096, 16384), ("nproc", 4096, 32768))


def ulimits() -> list[Any]:
    """``docker.types.Ulimit`` objects to pass on every container started through the API."""
    import docker

    return [docker.types.Ulimit(name=n, soft=s, hard=h) for n, s, h in ULIMIT_SPEC]


class PodmanService:
    """``podman system service`` on a socket in a temp dir; ``client`` is a DockerClient."""

    def __init__(self, workdir: Path | None = None) -> None:
        self._owns_workdir = workdir is None
        self.workdir = workdir or Path(tempfile.mkdtemp(prefix="armnet-podman-"))
        self.socket_path = self.workdir / "podman.sock"
        self.base_url = f"unix://{self.socket_path}"
        self.client: Any = None
        self._proc: ManagedProcess | None = None

    def start(self) -> PodmanService:
        podman = require_tool("podman")
        require_tool("runc")
        try:
            import docker
        except ImportError as exc:  # pragma: no cover - the venv always has it
            raise TestbedSetupError("the Python package `docker` is missing") from exc
        started = time.monotonic()
        self._proc = ManagedProcess("podman-service", [
            podman, "system", "service", "--time=0", self.base_url,
        ], self.workdir / "podman-service.log")
        proc = self._proc
        wait_until(self.socket_path.exists, timeout=30, what=f"podman socket {self.socket_path}",
                   alive=proc.ensure_running)
        self.client = docker.DockerClient(base_url=self.base_url, timeout=300)
        wait_until(self.client.ping, timeout=30, what="podman API ping", alive=proc.ensure_running)
        progress(f"podman API ready at {self.base_url} in {time.monotonic() - started:.1f} s")
        return self

    @property
    def pid(self) -> int:
        """The API service's process id (a benchmark reads its CPU time from /proc)."""
        if self._proc is None:
            raise RuntimeError("the Podman API service is not running: start() it first")
        return self._proc.proc.pid

    def stop(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        if self._proc is not None:
            self._proc.stop()
            self._proc = None
        if self._owns_workdir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> PodmanService:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
