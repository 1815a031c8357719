"""The binding kept per call shape (``motion._bindings``) holds only shapes that bind.

A tenant chooses the keyword names and the number of positional arguments of every
call. A shape ``Signature.bind`` refuses must not be kept: its key holds the
tenant's keyword names (up to a request line, 1 MiB, each), so 1,024 kept refusals
are about a gigabyte of the connector's memory, and a full table stops keeping the
control loop's own shape (its goal writes then never take the one-step check).
"""

from __future__ import annotations

from typing import Any

import pytest
from armnet_connector import motion
from armnet_connector.errors import RequestError
from armnet_runtime.wire import encode
from lerobot.motors.feetech import FeetechMotorsBus

pytestmark = pytest.mark.unit


def _kept_keyword_chars() -> int:
    return sum(len(name) for key in motion._bindings for name in key[3])


def test_refused_call_shapes_are_not_kept(monkeypatch: pytest.MonkeyPatch, motors: dict[str, Any]) -> None:
    monkeypatch.setattr(motion, "_bindings", {})
    bus = FeetechMotorsBus(port="/dev/null-armnet-test", motors=motors)
    for index in range(motion._MAX_BINDINGS + 50):
        name = f"k{index:05d}" + "x" * 2_000  # a hostile job's ever new, long keyword name
        with pytest.raises(RequestError):
            motion._bound_arguments(bus, "sync_write", ["Goal_Position", {"gripper": 1.0}], {name: 1})
        with pytest.raises(RequestError):  # and ever more positional arguments
            motion._bound_arguments(bus, "sync_write", ["Goal_Position"] * (3 + index), {})
    assert _kept_keyword_chars() < 10_000
    # The control loop's own shape is still kept (the one-step goal check depends on it).
    motion._bound_arguments(bus, "sync_write", ["Goal_Position", {"gripper": 1.0}], {})
    assert motion._bindings.get((type(bus), "sync_write", 2, ())) == ("data_name", "values")


def test_refused_shapes_through_the_connector_leave_the_table_small(
    monkeypatch: pytest.MonkeyPatch, sim_cell, make_connector, cell_config, client_for, motors, calibration
) -> None:
    monkeypatch.setattr(motion, "_bindings", {})
    connector = make_connector(cell_config(sim_cell, safetyPolicy="trip"))
    client = client_for(connector.robot_endpoint)
    bus = client.create("FeetechMotorsBus", port=connector.robot_endpoint, motors=motors, calibration=calibration)
    assert client.call(bus, "connect")["ok"]
    for index in range(200):
        reply = client.request({
            "op": "call", "object_id": bus, "method": "sync_write",
            "args": encode(["Goal_Position", {"gripper": 50.0}]), "kwargs": {f"{index}" + "y" * 20_000: 1},
        })
        assert not reply["ok"] and reply["error_type"] == "TypeError", reply
    assert _kept_keyword_chars() < 10_000
    assert not connector.interlock.tripped
