"""Hostile and random requests: the connector always answers well-formed replies and never
reaches a name outside the allow-list on a real object.

Each example starts a connector of its own (a request may trip its interlock or close its
bus), ~0.8 s: the suite runs 30; ``ARMNET_FUZZ_EXAMPLES=500`` (or
``bench/connector_policy_fuzz.sh``, which runs this fuzzer and the policy's) runs it longer.
"""

from __future__ import annotations

import json
import os
import socket
import sys
from typing import Any

import pytest
from armnet_connector import Connector, LocalOperatorInputs
from armnet_connector.allowlist import FEETECH
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.unit

EXAMPLES = int(os.environ.get("ARMNET_FUZZ_EXAMPLES", "30"))

NAMES = sorted(FEETECH.methods | FEETECH.readable) + [
    "__class__", "__dict__", "__init__", "__reduce__", "_comm_success", "_read", "port_handler",
    "packet_handler", "setup_motor", "scan_port", "set_baudrate", "__globals__", "mro",
]
OPS = [
    "hello", "create", "getattr", "setattr", "call", "enter", "exit", "close", "return_to_rest",
    "is_complete", "reset", "get_teleop", "get_teleop_event", "rollout_begin", "rollout_end",
    "get_completion", "shutdown_status", "should_stop",
]
KINDS = ["ndarray", "npscalar", "bytes", "tuple", "dict", "float", "path", "enum", "dataclass", "pickle", "module"]

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**40), 2**40) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)
tagged_values = st.builds(
    lambda kind, extra: {"__armnet__": kind, **extra},
    st.sampled_from(KINDS),
    st.dictionaries(
        st.sampled_from(["dtype", "shape", "data", "items", "value", "type", "fields"]),
        json_values | st.sampled_from(["os.system", "subprocess.Popen", "Motor", "MotorCalibration", "uint8"]),
        max_size=4,
    ),
)
values = st.one_of(json_values, tagged_values, st.lists(tagged_values, max_size=3))
requests = st.fixed_dictionaries(
    {"op": st.sampled_from(OPS) | st.text(max_size=12)},
    optional={
        "class": st.sampled_from(["FeetechMotorsBus", "OpenCVCamera", "ARX5Arm", "os.system", "__builtins__"]),
        "object_id": st.sampled_from(["o1", "o2", "c3", "", "../o1"]) | st.integers(),
        "name": st.sampled_from(NAMES) | st.text(max_size=12),
        "method": st.sampled_from(NAMES) | st.text(max_size=12),
        "args": values,
        "kwargs": values,
        "value": values,
        "block": values,
        "index": values,
        "exc_type": st.sampled_from(["ValueError", "SystemExit", "KeyboardInterrupt"]) | values,
    },
)
lines = st.one_of(
    requests.map(lambda r: json.dumps(r).encode()),
    st.binary(max_size=200).map(lambda b: b.replace(b"\n", b"")),
    json_values.map(lambda v: json.dumps(v).encode()),
)


#: The bus itself (a LeRobot subclass): its own attribute use is the bus's, like LeRobot's internals.
BUS_MODULE = "armnet_connector.policed_bus"


def _connector_code(caller: str) -> bool:
    return caller.startswith("armnet_connector") and caller != BUS_MODULE


class Recorder:
    """Names the connector's own code reads from real buses (LeRobot's internals are not counted)."""

    def __init__(self) -> None:
        self.names: set[str] = set()


@pytest.fixture
def recorder(monkeypatch: pytest.MonkeyPatch) -> Recorder:
    from lerobot.motors.feetech import FeetechMotorsBus

    record = Recorder()
    original_get = FeetechMotorsBus.__getattribute__
    original_set = FeetechMotorsBus.__setattr__

    def get(self: Any, name: str) -> Any:
        caller = sys._getframe(1).f_globals.get("__name__", "")
        if _connector_code(caller):
            record.names.add(name)
        return original_get(self, name)

    def set_(self: Any, name: str, value: Any) -> None:
        caller = sys._getframe(1).f_globals.get("__name__", "")
        if _connector_code(caller) or caller == "builtins":
            record.names.add(f"set:{name}")
        original_set(self, name, value)

    monkeypatch.setattr(FeetechMotorsBus, "__getattribute__", get)
    monkeypatch.setattr(FeetechMotorsBus, "__setattr__", set_)
    return record


def check_reply(raw: bytes) -> dict[str, Any]:
    assert raw.endswith(b"\n"), raw[:200]
    reply = json.loads(raw)
    assert isinstance(reply, dict) and isinstance(reply.get("ok"), bool), reply
    if not reply["ok"]:
        assert isinstance(reply.get("error"), str) and isinstance(reply.get("error_type"), str), reply
        assert "Traceback" not in reply["error"]
    return reply


@settings(max_examples=EXAMPLES, deadline=None, database=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(batch=st.lists(lines, min_size=1, max_size=8))
def test_random_and_hostile_requests_always_get_a_well_formed_reply(
    batch: list[bytes], socket_dir, cell_config, motors, recorder
) -> None:
    config = cell_config(None, resetTimeoutSeconds=0.05)
    with Connector(config, socket_dir, inputs=LocalOperatorInputs()) as connector:
        for sock_name in ("robot.sock", "operator.sock"):
            with socket.socket(socket.AF_UNIX) as sock:
                sock.settimeout(20)
                sock.connect(str(socket_dir / sock_name))
                reader = sock.makefile("rb")
                if sock_name == "robot.sock":
                    from armnet_runtime.wire import encode

                    create = {"op": "create", "class": "FeetechMotorsBus",
                              "kwargs": encode({"port": connector.robot_endpoint, "motors": motors})}
                    sock.sendall(json.dumps(create).encode() + b"\n")
                    assert check_reply(reader.readline())["ok"]
                for line in batch:
                    sock.sendall(line + b"\n")
                    check_reply(reader.readline())
                sock.sendall(b'{"op": "hello"}\n')
                assert check_reply(reader.readline())["ok"]
                if sock_name == "robot.sock":
                    # A known read, so the instrument is shown to see what the connector reaches.
                    # On a bus of its own: the batch may have closed o1.
                    sock.sendall(json.dumps(create).encode() + b"\n")
                    fresh = check_reply(reader.readline())["object_id"]
                    read = {"op": "getattr", "object_id": fresh, "name": "is_connected"}
                    sock.sendall(json.dumps(read).encode() + b"\n")
                    assert check_reply(reader.readline())["ok"]
    allowed = FEETECH.methods | FEETECH.readable | {f"set:{name}" for name in FEETECH.writable}
    assert "is_connected" in recorder.names
    assert recorder.names <= allowed, recorder.names - allowed
