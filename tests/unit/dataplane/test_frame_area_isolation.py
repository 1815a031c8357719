"""Who may touch a frame area: the job it was made for may read it, nobody may write it, other jobs see nothing.

The connector creates each area with mode 0440, group-owned by the socket
directory's group (in a pod: the ``fsGroup`` given to that job alone). The
checks run a real process under each identity (the tests run as root, which
file modes do not bind); it uses the system Python, standard library only.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest
from armnet_connector.frames import FramePublisher
from armnet_runtime.frames import MAGIC

pytestmark = pytest.mark.unit

SYSTEM_PYTHON = "/usr/bin/python3"
JOB_A = 42420  # uid and gid of the job the area is for
JOB_B = 42430  # another job on the same host

PROBE = """
import json, mmap, os, sys
path, outcome = sys.argv[1], {}
def attempt(name, action):
    try:
        outcome[name] = action()
    except OSError as exc:
        outcome[name] = type(exc).__name__
def read_magic():
    with open(path, "rb") as f:
        return f.read(8).decode()
def open_for_writing():
    with open(path, "r+b"):
        return "opened"
def map_writable():
    fd = os.open(path, os.O_RDONLY)
    try:
        mmap.mmap(fd, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE)
        return "mapped"
    finally:
        os.close(fd)
attempt("read", read_magic)
attempt("write", open_for_writing)
attempt("map_writable", map_writable)
print(json.dumps(outcome))
"""


def probe_as(uid: int, path: Path) -> dict[str, str]:
    assert os.path.exists(SYSTEM_PYTHON), f"{SYSTEM_PYTHON} is missing: run scripts/setup.sh"
    result = subprocess.run(
        [SYSTEM_PYTHON, "-c", PROBE, str(path)], user=uid, group=uid, extra_groups=[],
        capture_output=True, text=True, timeout=30, check=True,
    )
    outcome: dict[str, str] = json.loads(result.stdout)
    return outcome


@pytest.fixture
def job_area(socket_dir: Path) -> Path:
    """An area published into job A's socket directory (group A, setgid, as an emptyDir with fsGroup)."""
    os.chown(socket_dir, 0, JOB_A)
    socket_dir.chmod(0o2775)
    descriptor = FramePublisher(socket_dir, "front").publish(np.ones((480, 640, 3), np.uint8))
    assert descriptor is not None
    return socket_dir / descriptor["area"]


def test_an_area_is_created_read_only_for_its_owner_and_its_jobs_group_only(job_area: Path) -> None:
    info = job_area.stat()
    assert stat.S_IMODE(info.st_mode) == 0o440
    assert info.st_gid == JOB_A


def test_the_job_can_read_its_area_but_cannot_open_or_map_it_for_writing(job_area: Path) -> None:
    outcome = probe_as(JOB_A, job_area)
    assert outcome["read"] == MAGIC.decode()
    assert outcome["write"] == "PermissionError"
    assert outcome["map_writable"] == "PermissionError"


def test_another_job_cannot_open_the_area_at_all(job_area: Path) -> None:
    outcome = probe_as(JOB_B, job_area)
    assert outcome == {"read": "PermissionError", "write": "PermissionError", "map_writable": "PermissionError"}


def test_the_area_is_removed_when_its_camera_object_goes_away(socket_dir: Path) -> None:
    publisher = FramePublisher(socket_dir, "front")
    descriptor = publisher.publish(np.ones((8, 8), np.uint8))
    assert descriptor is not None and (socket_dir / descriptor["area"]).exists()
    publisher.close()
    assert not (socket_dir / descriptor["area"]).exists()
    assert publisher.publish(np.ones((8, 8), np.uint8)) is None
