"""Reads outside the allow-list: plain facts, a refused method that still exists, or absence.

On the wire, against the real connector and LeRobot's FeetechMotorsBus on the simulator.
"""

from __future__ import annotations

import sys

import pytest
from armnet_connector.warm_imports import start_warm_imports
from armnet_runtime.wire import decode

pytestmark = pytest.mark.unit


@pytest.fixture
def connector(make_connector, cell_config):
    return make_connector(cell_config(None))


@pytest.fixture
def bus(connector, client_for, motors):
    client = client_for(connector.robot_endpoint)
    return client, client.create("FeetechMotorsBus", port=connector.robot_endpoint, motors=motors)


def getattr_reply(bus, name: str) -> dict:
    client, object_id = bus
    return client.request({"op": "getattr", "object_id": object_id, "name": name})


def test_a_refused_method_of_the_real_class_reads_as_callable_and_its_call_is_refused(bus) -> None:
    assert getattr_reply(bus, "setup_motor") == {"ok": True, "callable": True}
    client, object_id = bus
    reply = client.request({"op": "call", "object_id": object_id, "method": "setup_motor", "args": ["gripper"]})
    assert reply["error_type"] == "NotAllowed" and "setup_motor" in reply["error"]


def test_a_name_the_real_object_lacks_is_an_attribute_error(bus) -> None:
    assert getattr_reply(bus, "use_depth")["error_type"] == "AttributeError"


def test_a_live_helper_is_refused_not_handed_out(bus) -> None:
    assert getattr_reply(bus, "sync_reader")["error_type"] == "NotAllowed"


def test_the_control_table_reads_as_plain_data(bus) -> None:
    reply = getattr_reply(bus, "model_ctrl_table")
    assert decode(reply["value"])["sts3215"]["Goal_Position"] == (42, 2)


def test_the_port_handler_reads_as_a_snapshot_naming_the_customers_endpoint(bus, connector) -> None:
    reply = getattr_reply(bus, "port_handler")
    assert reply["view"] is True
    assert decode(reply["value"]) == {"port_name": connector.robot_endpoint, "baudrate": 1_000_000, "is_open": False}


def test_a_private_name_stays_refused(bus) -> None:
    assert getattr_reply(bus, "_comm_success")["error_type"] == "NotAllowed"


def test_warm_imports_load_the_modules_and_survive_one_that_fails(caplog) -> None:
    start_warm_imports(("colorsys", "armnet_no_such_module")).join(timeout=30)
    assert "colorsys" in sys.modules
    assert "armnet_no_such_module" in caplog.text
