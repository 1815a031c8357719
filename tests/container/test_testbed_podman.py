"""The test bed's container engine is real: Podman + runc through the Docker API."""

from __future__ import annotations

import socket
import tempfile
import threading
from pathlib import Path

import pytest
from armnet_testbed.plugin import Podman

pytestmark = pytest.mark.container

# Runs inside the container: read the mounted file, ask the host over the unix socket
# in the same mount, print the answer, exit with a code the test checks.
CONTAINER_SCRIPT = """
import socket, sys
text = open('/work/input.txt').read().strip()
s = socket.socket(socket.AF_UNIX)
s.connect('/work/host.sock')
s.sendall(text.encode() + b'\\n')
reply = s.makefile().readline().strip()
print('file said', text, flush=True)
print('host said', reply, flush=True)
print('to stderr', file=sys.stderr, flush=True)
sys.exit(7)
"""


def _serve_once(sock_path: Path, received: list[str]) -> threading.Thread:
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(sock_path))
    sock_path.chmod(0o777)
    server.listen(1)
    server.settimeout(60)

    def handle() -> None:
        with server:
            conn, _ = server.accept()
            with conn:
                line = conn.makefile().readline().strip()
                received.append(line)
                conn.sendall(f"HELLO {line.upper()}\n".encode())

    thread = threading.Thread(target=handle, daemon=True)
    thread.start()
    return thread


def run_to_exit(podman: Podman, image: str, command: list[str]) -> tuple[int, str]:
    """Run a container to its exit; return its exit code and stdout.

    Not ``containers.run(remove=True)``: that follows the log stream, and with
    Podman 4.3's Docker API a follow attached after a fast container exited can
    stay open forever. Waiting for the exit, then reading the finished log, cannot.
    """
    container = podman.client.containers.run(
        image, command, network_mode="host", ulimits=podman.ulimits(), detach=True,
    )
    try:
        exit_code = container.wait(timeout=120)["StatusCode"]
        return exit_code, container.logs(stdout=True, stderr=False).decode()
    finally:
        container.remove(force=True)


def test_a_container_reads_a_mount_talks_to_the_host_and_reports_exit_code_and_logs(
    podman: Podman, base_image: str,
) -> None:
    with tempfile.TemporaryDirectory(prefix="armnet-mount-") as tmp:
        work = Path(tmp)
        (work / "input.txt").write_text("so-101 ready\n")
        received: list[str] = []
        server = _serve_once(work / "host.sock", received)

        container = podman.client.containers.run(
            base_image, ["python3", "-c", CONTAINER_SCRIPT],
            volumes={str(work): {"bind": "/work", "mode": "rw"}},
            network_mode="host", ulimits=podman.ulimits(), detach=True,
        )
        try:
            exit_code = container.wait(timeout=120)["StatusCode"]
            stdout = container.logs(stdout=True, stderr=False).decode()
            stderr = container.logs(stdout=False, stderr=True).decode()
        finally:
            container.remove(force=True)
        server.join(timeout=10)

    assert received == ["so-101 ready"]
    assert exit_code == 7
    assert stdout.splitlines() == ["file said so-101 ready", "host said HELLO SO-101 READY"]
    assert stderr.strip() == "to stderr"


def test_containers_run_with_runc_and_the_explicit_ulimits(podman: Podman, base_image: str) -> None:
    exit_code, output = run_to_exit(podman, base_image, ["bash", "-c", "ulimit -Sn; ulimit -Hn; ulimit -Su; ulimit -Hu"])

    assert exit_code == 0
    assert output.split() == ["4096", "16384", "4096", "32768"]
    assert podman.client.info()["DefaultRuntime"] == "runc"
