"""The proxies answer Python's object protocols as the LeRobot objects they stand for.

Against a real JSON-lines server (tests/support/jsonl_server_objects.py) whose
objects refuse some names the way the connector does (``NotAllowed``).
"""

from __future__ import annotations

import abc
import json
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_runtime.errors import RemoteAttributeError, RemoteCallError
from armnet_runtime.lerobot import (
    DeviceRefused,
    ReadOnlyView,
    RemoteFeetechMotorsBus,
    RemoteOpenCVCamera,
)
from armnet_runtime.lerobot.import_swap import register_virtual_bases

from tests.support.jsonl_server_objects import ObjectServer

pytestmark = pytest.mark.unit


class NotAllowed(Exception):
    """Raised by the demo objects; its class name is the wire error type, as the connector's refusal."""


class RefusingBus:
    def __init__(self, port: str, motors: dict[str, Any]) -> None:
        if "ttyUSB" in port:
            raise NotAllowed(f"port {port!r} is not this cell's connector endpoint")
        self.motors = motors

    @property
    def sync_reader(self) -> Any:
        raise NotAllowed("FeetechMotorsBus.sync_reader may not be read through the cell connector")

    def setup_motor(self, motor: str) -> None:
        raise NotAllowed("FeetechMotorsBus.setup_motor may not be called through the cell connector")


class Camera:
    def __init__(self, config: Any) -> None:
        self.is_connected = False

    def connect(self) -> None:
        self.is_connected = True

    def disconnect(self) -> None:
        self.is_connected = False


@pytest.fixture
def server(monkeypatch: pytest.MonkeyPatch) -> Iterator[ObjectServer]:
    directory = Path(tempfile.mkdtemp(prefix="armf", dir="/tmp"))
    srv = ObjectServer(str(directory / "robot.sock"), {"FeetechMotorsBus": RefusingBus, "OpenCVCamera": Camera}).start()
    monkeypatch.setenv("ARMNET_CELL_SOCKET", srv.endpoint)
    yield srv
    srv.stop()
    shutil.rmtree(directory, ignore_errors=True)


def test_a_refused_read_is_a_missing_attribute_and_is_not_asked_twice(server: ObjectServer) -> None:
    bus = RemoteFeetechMotorsBus(port=server.endpoint, motors={})
    assert hasattr(bus, "sync_reader") is False
    assert getattr(bus, "sync_reader", "default") == "default"
    with pytest.raises(RemoteAttributeError, match="may not be read"):
        bus.sync_reader  # noqa: B018 - the read is the behaviour under test
    assert server.count("getattr", "sync_reader") == 1


def test_a_refused_call_stays_a_clear_error(server: ObjectServer) -> None:
    bus = RemoteFeetechMotorsBus(port=server.endpoint, motors={})
    with pytest.raises(RemoteCallError, match="setup_motor may not be called") as caught:
        bus.setup_motor("gripper")
    assert caught.value.error_type == "NotAllowed"


def test_a_refused_port_is_a_connection_error(server: ObjectServer) -> None:
    with pytest.raises(ConnectionError) as caught:
        RemoteFeetechMotorsBus(port="/dev/ttyUSB3", motors={})
    assert isinstance(caught.value, DeviceRefused) and isinstance(caught.value, RemoteCallError)
    assert "ttyUSB3" in str(caught.value)


def test_the_camera_proxy_is_a_context_manager_that_connects_and_disconnects(server: ObjectServer) -> None:
    with RemoteOpenCVCamera({"index_or_path": "front"}) as cam:
        assert cam.is_connected is True
    assert server.count("call", "disconnect") == 1


def test_find_cameras_lists_the_cells_cameras(monkeypatch: pytest.MonkeyPatch) -> None:
    cell = {"camera_configs": {"front": {"index_or_path": "front", "fps": 30, "width": 640, "height": 480}}}
    monkeypatch.setenv("ARMNET_CELL_CONFIG", json.dumps(cell))
    (found,) = RemoteOpenCVCamera.find_cameras()
    assert found["id"] == "front" and found["type"] == "OpenCV"
    assert found["default_stream_profile"]["width"] == 640


def test_the_proxy_becomes_a_virtual_subclass_of_the_originals_abstract_bases() -> None:
    class Bus(abc.ABC):  # noqa: B024 - stands in for LeRobot's MotorsBusBase
        pass

    class Feetech(Bus):
        pass

    assert register_virtual_bases(Feetech, RemoteFeetechMotorsBus) == [Bus.__qualname__]
    assert issubclass(RemoteFeetechMotorsBus, Bus)
    assert not issubclass(RemoteFeetechMotorsBus, Feetech)


def test_a_read_only_view_answers_its_values_and_refuses_the_rest() -> None:
    view = ReadOnlyView("port_handler", {"baudrate": 1_000_000})
    assert view.baudrate == 1_000_000
    assert getattr(view, "ser", None) is None
    with pytest.raises(AttributeError):
        view.baudrate = 9600
