"""The test beds' ports: never the same port twice, to this process or to another one."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
from pathlib import Path

import pytest
from armnet_testbed.procs import PORT_CLAIMS, free_port

REPO = Path(__file__).resolve().parents[3]


def test_ports_in_a_row_differ_and_lie_below_the_ephemeral_range() -> None:
    # etcd's client and peer ports were picked in a row, and once were the same port.
    ports = [free_port() for _ in range(50)]
    assert len(set(ports)) == len(ports)
    low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    assert all(1024 <= port < low for port in ports)  # no bind(0) or outgoing connection takes them


def test_a_port_another_process_claimed_stays_its_own_while_it_lives() -> None:
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from armnet_testbed.procs import free_port; "
         "print(free_port(), flush=True); sys.stdin.read()"],
        cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None
        port = int(holder.stdout.readline())
        fd = os.open(PORT_CLAIMS / str(port), os.O_RDWR)
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            assert holder.stdin is not None
            holder.stdin.close()  # the holder exits: its claim goes with it
            holder.wait(30)
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)
    finally:
        holder.kill()
        holder.wait()
