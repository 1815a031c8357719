"""The cell device plugin's decisions: one resource per cell, health from its device paths, how each device is given."""

from __future__ import annotations

import pytest
from armnet_node.deviceplugin.decide import (
    HEALTHY,
    UNHEALTHY,
    AllocationRefused,
    DeviceFact,
    DeviceGrant,
    DevicePath,
    MountGrant,
    allocate,
    cell_device_paths,
    health,
    resource_name,
)

pytestmark = pytest.mark.unit

ARM = DevicePath("/dev/armnet/arm", "/dev/serial/by-id/usb-1a86_USB_Single_Serial_5A46-if00-port0")


def present(path: DevicePath, resolved: str) -> DeviceFact:
    return DeviceFact(path, resolved, is_char_device=True)


def test_each_cell_has_its_own_resource_under_armnet_io() -> None:
    assert resource_name("lab-a.cell-1") == "armnet.io/cell-lab-a.cell-1"


def test_a_cell_name_too_long_for_an_extended_resource_is_refused_with_the_way_out() -> None:
    with pytest.raises(ValueError, match="--no-device-plugin"):
        resource_name("c" * 60)


def test_arms_go_to_their_connector_path_and_cameras_keep_their_own_path() -> None:
    paths = cell_device_paths({"right": "/dev/ttyUSB1", "left": "/dev/ttyUSB0"}, (0, "/dev/v4l/by-id/cam-wrist"))
    assert paths == (
        DevicePath("/dev/armnet/left", "/dev/ttyUSB0"),
        DevicePath("/dev/armnet/right", "/dev/ttyUSB1"),
        DevicePath("/dev/video0", "/dev/video0"),
        DevicePath("/dev/v4l/by-id/cam-wrist", "/dev/v4l/by-id/cam-wrist"),
    )


def test_the_device_is_healthy_while_every_path_is_a_character_device() -> None:
    camera = DevicePath("/dev/video0", "/dev/video0")
    assert health([present(ARM, "/dev/ttyUSB0"), present(camera, "/dev/video0")]) == HEALTHY


def test_the_device_is_unhealthy_when_one_path_vanished() -> None:
    camera = DevicePath("/dev/video0", "/dev/video0")
    assert health([present(ARM, "/dev/ttyUSB0"), DeviceFact(camera, None, False)]) == UNHEALTHY


def test_a_path_that_is_no_character_device_is_unhealthy() -> None:
    assert health([DeviceFact(ARM, "/tmp/not-a-device", is_char_device=False)]) == UNHEALTHY


def test_a_cell_without_any_device_is_unhealthy() -> None:
    assert health([]) == UNHEALTHY


def test_a_serial_adapter_is_given_as_a_device_spec_of_its_resolved_node() -> None:
    allocation = allocate([present(ARM, "/dev/ttyUSB0")])
    assert allocation.devices == (DeviceGrant("/dev/armnet/arm", "/dev/ttyUSB0", "rw"),)
    assert allocation.mounts == ()


def test_a_simulators_pty_is_given_as_a_bind_mount_not_a_device_spec() -> None:
    pty = DevicePath("/dev/armnet/arm", "/dev/pts/7")
    allocation = allocate([present(pty, "/dev/pts/7")])
    assert allocation.mounts == (MountGrant("/dev/armnet/arm", "/dev/pts/7", read_only=False),)
    assert allocation.devices == ()


def test_an_allocation_with_a_missing_device_is_refused_naming_the_path() -> None:
    camera = DevicePath("/dev/video0", "/dev/video0")
    with pytest.raises(AllocationRefused, match="/dev/video0 does not exist"):
        allocate([present(ARM, "/dev/ttyUSB0"), DeviceFact(camera, None, False)])


def test_an_arm_without_a_configured_port_is_refused() -> None:
    with pytest.raises(AllocationRefused, match="no host path configured for /dev/armnet/arm"):
        allocate([DeviceFact(DevicePath("/dev/armnet/arm", ""), None, False)])
