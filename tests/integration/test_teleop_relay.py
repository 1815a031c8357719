"""armnet's teleop relay as LeRobot's teleoperator, against a real connector on the simulated SO-101.

LeRobot's own factory (``make_teleoperator_from_config``) must find the relay from its
config, and each action it hands the recording loop must be the operator's freshest,
laid over the pose it holds, read through the connector's operator socket.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from armnet_connector import Connector, LocalOperatorInputs
from armnet_runtime.lerobot.teleop import ArmnetRelay, ArmnetRelayConfig
from armnet_sim import SimulatedCellProcess
from lerobot.teleoperators.utils import make_teleoperator_from_config

from tests.support.sim_connector import cell_config

pytestmark = pytest.mark.integration

HOLD = {"shoulder_pan.pos": 1.0, "elbow_flex.pos": 2.0, "gripper.pos": 30.0}


@pytest.fixture
def cell(sim: SimulatedCellProcess) -> Iterator[tuple[Connector, LocalOperatorInputs]]:
    socket_dir = Path(tempfile.mkdtemp(prefix="arl-", dir="/tmp"))
    inputs = LocalOperatorInputs()
    connector = Connector(cell_config(sim), socket_dir, inputs=inputs).start()
    yield connector, inputs
    connector.stop()
    shutil.rmtree(socket_dir, ignore_errors=True)


def test_lerobots_factory_builds_the_relay_which_holds_until_the_operator_moves_a_joint(
        cell: tuple[Connector, LocalOperatorInputs]) -> None:
    connector, inputs = cell
    relay = make_teleoperator_from_config(ArmnetRelayConfig(hold=HOLD, operator_call_endpoint=connector.operator_endpoint))
    assert isinstance(relay, ArmnetRelay) and relay.action_features == dict.fromkeys(HOLD, float)
    relay.connect()
    try:
        assert relay.get_action() == HOLD
        inputs.set_teleop_action({"elbow_flex": 12.5, "wrist_roll": 7.0})  # bare names, as a leader's bus reads them
        assert relay.get_action() == {**HOLD, "elbow_flex.pos": 12.5}
        inputs.set_teleop_action({"shoulder_pan.pos": -3.0})
        assert relay.get_action() == {**HOLD, "elbow_flex.pos": 12.5, "shoulder_pan.pos": -3.0}
        inputs.set_teleop_action(None)  # the operator let go: the last action is held
        assert relay.get_action() == {**HOLD, "elbow_flex.pos": 12.5, "shoulder_pan.pos": -3.0}
    finally:
        relay.disconnect()
    assert not relay.is_connected


def test_a_relay_without_its_endpoint_holds_position() -> None:
    relay = ArmnetRelay(ArmnetRelayConfig(hold=HOLD))
    relay.connect()
    assert relay.get_action() == HOLD


def test_a_relay_with_nothing_to_hold_says_what_to_give() -> None:
    with pytest.raises(ValueError, match=r"hold is empty: name every action key"):
        ArmnetRelay(ArmnetRelayConfig())


def test_a_relay_asked_before_connect_says_so() -> None:
    with pytest.raises(RuntimeError, match="not connected: call connect"):
        ArmnetRelay(ArmnetRelayConfig(hold=HOLD)).get_action()
