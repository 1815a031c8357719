"""The cell plugin's gRPC answers, asked over its unix socket the way the kubelet asks (no kubelet needed)."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import grpc
import pytest
from armnet_node.deviceplugin.decide import cell_device_paths, socket_name
from armnet_node.deviceplugin.server import DevicePlugins
from armnet_node.deviceplugin.v1beta1 import api_pb2, api_pb2_grpc
from armnet_node.metrics import AgentMetrics

pytestmark = pytest.mark.unit

CELL = "grpc-cell"


@pytest.fixture
def arm_link(tmp_path: Path) -> Iterator[Path]:
    master, slave = os.openpty()
    link = tmp_path / "arm-by-id"
    link.symlink_to(os.ttyname(slave))
    try:
        yield link
    finally:
        os.close(master)
        os.close(slave)


@pytest.fixture
def stub(arm_link: Path) -> Iterator[api_pb2_grpc.DevicePluginStub]:
    # A short directory (a unix socket path must stay under 108 bytes), without a kubelet.sock:
    # the plugin serves and waits to register.
    directory = Path(tempfile.mkdtemp(prefix="armnet-dp-", dir="/tmp"))
    plugins = DevicePlugins(AgentMetrics(), directory, check_s=0.2)
    plugins.sync({CELL: lambda: cell_device_paths({"arm": str(arm_link)})})
    try:
        with grpc.insecure_channel(f"unix://{directory / socket_name(CELL)}") as channel:
            yield api_pb2_grpc.DevicePluginStub(channel)
    finally:
        plugins.stop()
        shutil.rmtree(directory, ignore_errors=True)


def test_allocate_bind_mounts_the_cells_pty_at_the_connectors_device_path(
    stub: api_pb2_grpc.DevicePluginStub, arm_link: Path
) -> None:
    request = api_pb2.AllocateRequest(container_requests=[api_pb2.ContainerAllocateRequest(devices_ids=[CELL])])
    (response,) = stub.Allocate(request, timeout=5).container_responses
    assert [(m.container_path, m.host_path, m.read_only) for m in response.mounts] == [
        ("/dev/armnet/arm", os.path.realpath(arm_link), False)]
    assert list(response.devices) == []


def test_list_and_watch_reports_the_cell_device_healthy_then_unhealthy_when_its_path_goes(
    stub: api_pb2_grpc.DevicePluginStub, arm_link: Path
) -> None:
    stream = stub.ListAndWatch(api_pb2.Empty(), timeout=10)
    first = next(stream)
    assert [(d.ID, d.health) for d in first.devices] == [(CELL, "Healthy")]
    arm_link.unlink()
    second = next(stream)
    assert [(d.ID, d.health) for d in second.devices] == [(CELL, "Unhealthy")]
    stream.cancel()


def test_allocate_of_a_vanished_device_is_refused_naming_its_path(
    stub: api_pb2_grpc.DevicePluginStub, arm_link: Path
) -> None:
    arm_link.unlink()
    request = api_pb2.AllocateRequest(container_requests=[api_pb2.ContainerAllocateRequest(devices_ids=[CELL])])
    with pytest.raises(grpc.RpcError) as raised:
        stub.Allocate(request, timeout=5)
    assert raised.value.code() == grpc.StatusCode.FAILED_PRECONDITION
    assert f"{arm_link} does not exist" in raised.value.details()
