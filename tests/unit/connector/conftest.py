"""Fixtures for the connector tests: a simulated SO-101 on a pty and a connector on real sockets."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
from armnet_connector import Connector, ConnectorConfig, LocalOperatorInputs
from armnet_runtime.transport import PersistentConnection
from armnet_runtime.wire import decode, encode
from armnet_sim import SimulatedCellProcess


def calibration_file(name: str = "so101") -> Path:
    return Path(str(resources.files("armnet_sim.data").joinpath(f"{name}.json")))


@pytest.fixture
def socket_dir() -> Iterator[Path]:
    # Unix socket paths are limited to 108 bytes: pytest's tmp_path is often longer.
    path = Path(tempfile.mkdtemp(prefix="anc-", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def sim_cell() -> Iterator[SimulatedCellProcess]:
    cell = SimulatedCellProcess("so101").start()
    yield cell
    cell.stop()


def so101_config(cell: SimulatedCellProcess | None, **overrides: Any) -> ConnectorConfig:
    port = cell.arm.port if cell is not None else "/dev/null-armnet-test"
    data: dict[str, Any] = {
        "arms": {
            "arm": {
                "port": port,
                "calibrationFile": str(calibration_file()),
                "robotId": "sim-so101",
                "safetyLimit": 30.0,
            }
        },
        "cameras": {"front": {"indexOrPath": 0, "fps": 30, "width": 640, "height": 480}},
        "simulated": True,
        "resetTimeoutSeconds": 2,
        "restSpeedTicksPerSecond": 4000,
    }
    data.update(overrides)
    return ConnectorConfig.model_validate(data)


@pytest.fixture
def make_connector(socket_dir: Path) -> Iterator[Callable[..., Connector]]:
    started: list[Connector] = []

    def make(config: ConnectorConfig, **kwargs: Any) -> Connector:
        kwargs.setdefault("inputs", LocalOperatorInputs())
        connector = Connector(config, socket_dir, **kwargs).start()
        started.append(connector)
        return connector

    yield make
    for connector in started:
        connector.stop()


class Client:
    """A raw protocol client on one persistent connection (the SDK's transport)."""

    def __init__(self, endpoint: str) -> None:
        self.conn = PersistentConnection(endpoint, timeout=30)

    def request(self, payload: dict[str, Any]) -> dict[str, Any]:
        return self.conn.request(payload)

    def create(self, cls: str, *args: Any, **kwargs: Any) -> str:
        reply = self.request({"op": "create", "class": cls, "args": encode(list(args)), "kwargs": encode(kwargs)})
        assert reply["ok"], reply
        return str(reply["object_id"])

    def call(self, object_id: str, method: str, *args: Any, **kwargs: Any) -> dict[str, Any]:
        return self.request(
            {"op": "call", "object_id": object_id, "method": method, "args": encode(list(args)), "kwargs": encode(kwargs)}
        )

    def value(self, object_id: str, method: str, *args: Any, **kwargs: Any) -> Any:
        reply = self.call(object_id, method, *args, **kwargs)
        assert reply["ok"], reply
        return decode(reply.get("value"))

    def close(self) -> None:
        self.conn.close()


@pytest.fixture
def client_for() -> Iterator[Callable[[str], Client]]:
    clients: list[Client] = []

    def make(endpoint: str) -> Client:
        client = Client(endpoint)
        clients.append(client)
        return client

    yield make
    for client in clients:
        client.close()


def so101_motors() -> dict[str, Any]:
    from lerobot.motors import Motor, MotorNormMode

    names = ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"]
    motors = {name: Motor(i + 1, "sts3215", MotorNormMode.DEGREES) for i, name in enumerate(names)}
    motors["gripper"] = Motor(6, "sts3215", MotorNormMode.RANGE_0_100)
    return motors


def so101_calibration() -> dict[str, Any]:
    import json

    from lerobot.motors import MotorCalibration

    data = json.loads(calibration_file().read_text())
    return {name: MotorCalibration(**entry) for name, entry in data.items()}


@pytest.fixture
def cell_config() -> Callable[..., ConnectorConfig]:
    """``cell_config(sim_cell, **overrides)``: the connector config of a simulated SO-101 cell."""
    return so101_config


@pytest.fixture
def motors() -> dict[str, Any]:
    return so101_motors()


@pytest.fixture
def calibration() -> dict[str, Any]:
    return so101_calibration()


@pytest.fixture
def calibration_path() -> Callable[[str], Path]:
    """``calibration_path("so101_left")``: a calibration file shipped with the simulator."""
    return calibration_file


# A test module that needs another policy or bus defines its own ``connector`` / ``bus``
# (a module's fixture takes precedence over these).
@pytest.fixture
def connector(sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
              cell_config: Callable[..., ConnectorConfig]) -> Connector:
    """A connector on the simulated SO-101 with the trip policy: an oversized step is refused
    (the default, clamp, is in test_connector_policy)."""
    return make_connector(cell_config(sim_cell, safetyPolicy="trip"))


@pytest.fixture
def bus(connector: Connector, motors: dict[str, Any], calibration: dict[str, Any]) -> Iterator[Any]:
    """LeRobot's bus through that connector (the SDK's proxy), connected with torque on."""
    from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

    remote = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    remote.connect()
    remote.enable_torque()
    yield remote
    if remote.is_connected:
        remote.disconnect()
