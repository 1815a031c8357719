"""The remote proxies against a real JSON-lines server on a unix socket.

The server (tests/support/jsonl_server_objects.py) serves a small bus-like
Python object; requests are counted server-side, so cache behaviour is asserted
on what actually crossed the socket.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from armnet_runtime.errors import (
    ConnectorUnavailable,
    ProtocolError,
    RemoteAttributeError,
    RemoteCallError,
    SafetyViolation,
)
from armnet_runtime.lerobot import (
    IS_CONNECTED_TTL_S,
    RemoteARX5Arm,
    RemoteContextManager,
    RemoteFeetechMotorsBus,
    RemoteOpenCVCamera,
)

from tests.support.jsonl_server_objects import ObjectServer

pytestmark = pytest.mark.unit

MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


class DemoBus:
    """A small bus-shaped object: the server-side stand-in for the connector's real bus."""

    def __init__(self, port: str, motors: dict[str, Any], calibration: Any = None) -> None:
        self.port = port
        self.motors = motors
        self.calibration = calibration
        self._connected = False
        self.torque = True
        self.goals: dict[str, float] = {}
        self.events: list[str] = []

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self, handshake: bool = True) -> None:
        if self._connected:
            raise RuntimeError("DemoBus is already connected")
        self._connected = True
        self.events.append(f"connect({handshake})")

    def disconnect(self, disable_torque: bool = True) -> None:
        self._connected = False

    def drop_link(self) -> None:
        """The far side loses the device without the proxy calling disconnect()."""
        self._connected = False

    def sync_read(self, data_name: str) -> dict[str, float]:
        return {name: 10.0 * i + 0.5 for i, name in enumerate(MOTORS)}

    def sync_write(self, data_name: str, values: dict[str, float]) -> None:
        if values.get("gripper", 0.0) > 90:
            raise SafetyViolationError("gripper step 95.0 exceeds the safety limit 10.0")
        self.goals.update(values)

    def broadcast_ping(self) -> dict[int, int]:
        return {1: 777, 2: 777}

    def frame(self) -> Any:
        return np.arange(480 * 640 * 3, dtype=np.uint32).astype(np.uint8).reshape(480, 640, 3)

    def fail(self, kind: str) -> None:
        raise {"value": ValueError, "key": KeyError, "timeout": TimeoutError, "custom": LookupError}[kind](kind)

    @contextlib.contextmanager
    def torque_disabled(self) -> Iterator[str]:
        self.torque = False
        self.events.append("torque off")
        try:
            yield "torque-is-off"
        finally:
            self.torque = True
            self.events.append("torque on")


class SafetyViolationError(Exception):
    pass


# The wire error type is the exception's class name; the connector's is "SafetyViolation".
SafetyViolationError.__name__ = "SafetyViolation"


@pytest.fixture
def sock_dir() -> Iterator[Path]:
    # Short path: a unix socket path must fit in 108 bytes.
    path = Path(tempfile.mkdtemp(prefix="armw", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def server(sock_dir: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[ObjectServer]:
    factories = {"FeetechMotorsBus": DemoBus, "OpenCVCamera": DemoCamera, "ARX5Arm": DemoCamera}
    srv = ObjectServer(str(sock_dir / "robot.sock"), factories).start()
    monkeypatch.setenv("ARMNET_CELL_SOCKET", srv.endpoint)
    yield srv
    srv.stop()


class DemoCamera:
    def __init__(self, config: Any) -> None:
        self.config = config
        self.is_connected = False

    def connect(self) -> None:
        self.is_connected = True

    def read_latest(self) -> Any:
        return np.full((480, 640, 3), 7, dtype=np.uint8)


def make_bus(server: ObjectServer, port: str | None = None) -> RemoteFeetechMotorsBus:
    return RemoteFeetechMotorsBus(port=port or server.endpoint, motors={"gripper": [6, "sts3215"]})


def test_calls_cross_the_socket_with_real_values(server: ObjectServer) -> None:
    bus = make_bus(server)
    bus.connect()
    positions = bus.sync_read("Present_Position")
    assert positions == {name: 10.0 * i + 0.5 for i, name in enumerate(MOTORS)}
    bus.sync_write("Goal_Position", {"gripper": 12.5})
    assert server.created[0].goals == {"gripper": 12.5}
    assert bus.broadcast_ping() == {1: 777, 2: 777}
    frame = bus.frame()
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    assert bus.motors == {"gripper": [6, "sts3215"]}
    assert server.requests[0]["op"] == "create" and server.requests[0]["class"] == "FeetechMotorsBus"


def test_method_names_are_resolved_once(server: ObjectServer) -> None:
    bus = make_bus(server)
    for _ in range(5):
        bus.sync_read("Present_Position")
    assert server.count("getattr", "sync_read") == 1
    assert server.count("call", "sync_read") == 5


def test_missing_attribute_is_negative_cached_and_defaults_work(server: ObjectServer) -> None:
    bus = make_bus(server)
    for _ in range(4):
        assert getattr(bus, "use_depth", False) is False
    assert not hasattr(bus, "use_depth")
    assert server.count("getattr", "use_depth") == 1
    with pytest.raises(RemoteAttributeError):
        bus.use_depth  # noqa: B018 - the attribute access is the behaviour under test
    with pytest.raises(AttributeError):
        bus.also_missing  # noqa: B018


def test_private_names_are_never_forwarded(server: ObjectServer) -> None:
    bus = make_bus(server)
    assert getattr(bus, "_connected_secret", "local") == "local"
    assert not hasattr(bus, "__len__")
    assert server.count("getattr") == 0


def test_setattr_forwards_public_names_and_clears_the_negative_cache(server: ObjectServer) -> None:
    bus = make_bus(server)
    assert getattr(bus, "extra", None) is None
    bus.extra = (1, 2)
    assert server.created[0].extra == (1, 2)
    assert bus.extra == (1, 2)
    bus._local = "stays here"
    assert server.count("setattr") == 1


def test_is_connected_is_served_from_the_ttl_cache(server: ObjectServer) -> None:
    bus = make_bus(server)
    assert bus.is_connected is False
    assert server.count("getattr", "is_connected") == 1
    bus.connect()
    for _ in range(10):
        assert bus.is_connected is True
    assert server.count("getattr", "is_connected") == 1
    server.created[0].drop_link()
    time.sleep(IS_CONNECTED_TTL_S + 0.05)
    assert bus.is_connected is False  # re-checked once the TTL ran out
    assert server.count("getattr", "is_connected") == 2
    bus.connect()
    bus.disconnect()
    assert bus.is_connected is False
    assert server.count("getattr", "is_connected") == 2


def test_remote_context_manager_enters_and_exits(server: ObjectServer) -> None:
    bus = make_bus(server)
    manager = bus.torque_disabled()
    assert isinstance(manager, RemoteContextManager)
    with manager as value:
        assert value == "torque-is-off"
        assert server.created[0].torque is False
    assert server.created[0].torque is True
    with pytest.raises(ValueError, match="inside"), bus.torque_disabled():
        raise ValueError("inside")
    assert server.created[0].events[-2:] == ["torque off", "torque on"]
    exits = [r for r in server.requests if r["op"] == "exit"]
    assert exits[-1]["exc_type"] == "ValueError" and exits[-1]["exc_message"] == "inside"


@pytest.mark.parametrize(
    ("kind", "expected"),
    [("value", ValueError), ("key", KeyError), ("timeout", TimeoutError), ("custom", RemoteCallError)],
)
def test_remote_errors_map_to_local_types(server: ObjectServer, kind: str, expected: type) -> None:
    bus = make_bus(server)
    with pytest.raises(expected):
        bus.fail(kind)
    bus.sync_read("Present_Position")  # the connection survives a failing call


def test_safety_violation_is_typed(server: ObjectServer) -> None:
    bus = make_bus(server)
    with pytest.raises(SafetyViolation, match="safety limit"):
        bus.sync_write("Goal_Position", {"gripper": 95.0})


def test_create_errors_surface(server: ObjectServer) -> None:
    with pytest.raises(TypeError):
        RemoteFeetechMotorsBus(server.endpoint)  # motors missing: the real constructor's TypeError


def test_endpoint_comes_from_port_and_keeps_the_arm_selector(
    server: ObjectServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("ARMNET_CELL_SOCKET")
    port = f"{server.endpoint}?arm=left"
    bus = RemoteFeetechMotorsBus(port, {"gripper": [6, "sts3215"]})
    assert server.created[0].port == port
    assert repr(bus).startswith("<RemoteFeetechMotorsBus o") and "robot.sock" in repr(bus)


def test_device_port_uses_the_cell_socket(server: ObjectServer) -> None:
    RemoteFeetechMotorsBus(port="/dev/ttyACM0", motors={})
    assert server.created[0].port == "/dev/ttyACM0"


def test_no_endpoint_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ARMNET_CELL_SOCKET", raising=False)
    with pytest.raises(ConnectorUnavailable, match="ARMNET_CELL_SOCKET"):
        RemoteFeetechMotorsBus(port="/dev/ttyACM0", motors={})
    with pytest.raises(ConnectorUnavailable, match="ARMNET_LOCAL_CONTAINER"):
        RemoteOpenCVCamera({"index_or_path": 0})


def test_unreachable_connector_is_a_connection_error(sock_dir: Path) -> None:
    with pytest.raises(ConnectionError, match="cannot reach the cell connector"):
        RemoteFeetechMotorsBus(port=f"unix://{sock_dir}/absent.sock", motors={})


def test_camera_and_arx5_share_the_proxy(server: ObjectServer) -> None:
    camera = RemoteOpenCVCamera({"index_or_path": "wrist"})
    camera.connect()
    assert camera.is_connected is True
    assert int(camera.read_latest()[0, 0, 0]) == 7
    arm = RemoteARX5Arm({"model": "X5"})
    assert arm.config == {"model": "X5"}
    assert [r["class"] for r in server.requests if r["op"] == "create"] == ["OpenCVCamera", "ARX5Arm"]


def test_reconnects_after_the_server_restarts(server: ObjectServer) -> None:
    bus = make_bus(server)
    bus.connect(handshake=False)
    bus.sync_read("Present_Position")
    server.restart()
    # The request could not be written to the dead connection, so the proxy
    # re-created the object on a new one, replayed connect() and retried.
    assert bus.sync_read("Present_Position")["gripper"] == 50.5
    assert len(server.created) == 2
    assert server.created[1].events == ["connect(False)"]
    assert bus.is_connected is True


def test_server_down_then_back(server: ObjectServer) -> None:
    bus = make_bus(server)
    server.stop()
    with pytest.raises(ConnectionError):
        bus.sync_read("Present_Position")
    server.start()
    assert bus.sync_read("Present_Position")["shoulder_pan"] == 0.5


class ShortTimeoutBus(RemoteFeetechMotorsBus):
    _call_timeout_s = 0.5


def test_wedged_peer_times_out_and_the_next_call_recovers(server: ObjectServer) -> None:
    bus = ShortTimeoutBus(port=server.endpoint, motors={})
    bus.sync_read("Present_Position")
    server.mode = "wedge"
    started = time.monotonic()
    with pytest.raises(ConnectorUnavailable, match="no reply"):
        bus.sync_read("Present_Position")
    assert time.monotonic() - started < 5
    server.mode = "normal"
    server.restart()
    assert bus.sync_read("Present_Position")["gripper"] == 50.5


def test_garbage_reply_is_a_clear_protocol_error(server: ObjectServer) -> None:
    bus = make_bus(server)
    server.mode = "garbage"
    with pytest.raises(ProtocolError, match="not JSON.*this is not json"):
        bus.sync_read("Present_Position")
    server.garbage = b'{"value": 1}\n'
    with pytest.raises(ProtocolError, match="boolean 'ok'"):
        bus.sync_read("Present_Position")
    server.mode = "normal"
    assert bus.sync_read("Present_Position")["gripper"] == 50.5


def test_unencodable_argument_fails_before_sending(server: ObjectServer) -> None:
    bus = make_bus(server)
    with pytest.raises(ProtocolError, match="cannot send"):
        bus.sync_write("Goal_Position", {"gripper": object()})
    assert server.count("call", "sync_write") == 0
    assert server.created[0].goals == {}


class SlowToCreateBus(DemoBus):
    """A connector whose first ``create`` of the class imports LeRobot's module first."""

    def __init__(self, port: str, motors: dict[str, Any], calibration: Any = None) -> None:
        time.sleep(1.5)
        super().__init__(port, motors, calibration)


def test_create_waits_past_the_call_timeout_for_a_connector_still_importing_the_class(sock_dir: Path) -> None:
    srv = ObjectServer(str(sock_dir / "robot.sock"), {"FeetechMotorsBus": SlowToCreateBus}).start()
    try:
        bus = ShortTimeoutBus(port=srv.endpoint, motors={})  # creating takes 3x its call timeout
        assert bus.sync_read("Present_Position")["gripper"] == 50.5
        srv.mode = "wedge"
        with pytest.raises(ConnectorUnavailable, match="no reply"):
            bus.sync_read("Present_Position")  # every other call keeps the class's own timeout
    finally:
        srv.stop()
