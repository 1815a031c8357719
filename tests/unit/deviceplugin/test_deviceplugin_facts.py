"""What the device plugin reads from the host: a pty behind a symlink resolves to its devpts node; a file is no device."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from armnet_node.deviceplugin.decide import DevicePath, MountGrant, allocate
from armnet_node.deviceplugin.facts import read_fact

pytestmark = pytest.mark.unit


@pytest.fixture
def pty_path() -> Iterator[str]:
    master, slave = os.openpty()
    try:
        yield os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


def test_a_symlinked_pty_resolves_to_its_devpts_node_and_is_bind_mounted(pty_path: str, tmp_path: Path) -> None:
    link = tmp_path / "usb-by-id-arm"
    link.symlink_to(pty_path)
    fact = read_fact(DevicePath("/dev/armnet/arm", str(link)))
    assert fact.resolved == os.path.realpath(pty_path) and fact.is_char_device
    assert allocate([fact]).mounts == (MountGrant("/dev/armnet/arm", fact.resolved),)


def test_a_dangling_symlink_reads_as_missing(tmp_path: Path) -> None:
    link = tmp_path / "unplugged"
    link.symlink_to(tmp_path / "gone")
    assert read_fact(DevicePath("/dev/armnet/arm", str(link))).resolved is None


def test_a_regular_file_is_no_character_device(tmp_path: Path) -> None:
    path = tmp_path / "not-a-tty"
    path.write_text("")
    fact = read_fact(DevicePath("/dev/armnet/arm", str(path)))
    assert fact.resolved == os.path.realpath(path) and not fact.is_char_device


def test_a_path_with_a_nul_byte_reads_as_missing_rather_than_raising() -> None:
    fact = read_fact(DevicePath("/dev/armnet/arm", "/dev/ttyACM0\x00evil"))
    assert fact.resolved is None and not fact.is_char_device
