"""robot.sock/operator.sock framing, allow-list and robustness, on real unix sockets."""

from __future__ import annotations

import socket
import threading
from pathlib import Path

import pytest
from armnet_connector.server import MAX_LINE_BYTES
from armnet_runtime.wire import encode

pytestmark = pytest.mark.unit


def raw_exchange(path: Path, data: bytes, *, read_reply: bool = True) -> bytes:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(10)
        sock.connect(str(path))
        sock.sendall(data)
        if not read_reply:
            return b""
        buffer = b""
        while not buffer.endswith(b"\n"):
            chunk = sock.recv(65536)
            if not chunk:
                break
            buffer += chunk
        return buffer


@pytest.fixture
def connector(make_connector, cell_config):
    return make_connector(cell_config(None))


def test_hello_names_the_socket_and_protocol(connector, client_for) -> None:
    robot = client_for(connector.robot_endpoint).request({"op": "hello"})
    operator = client_for(connector.operator_endpoint).request({"op": "hello"})
    assert (robot["ok"], robot["protocol"], robot["socket"]) == (True, 1, "robot")
    assert operator["socket"] == "operator" and operator["server"].startswith("armnet-connector/")


@pytest.mark.parametrize(
    ("line", "fragment"),
    [(b"not json\n", "not JSON"), (b"[1, 2]\n", "JSON object"), (b'{"op": 3}\n', "string 'op'"), (b"\xff\xfe\n", "not JSON")],
)
def test_malformed_lines_get_a_protocol_error_and_the_connection_stays_usable(connector, line, fragment) -> None:
    path = connector.socket_dir / "robot.sock"
    replies = raw_exchange(path, line + b'{"op": "hello"}\n')
    assert b'"error_type":"ProtocolError"' in replies and fragment.encode() in replies
    # The reply to the malformed line came first; the hello is answered on the same connection.
    with socket.socket(socket.AF_UNIX) as sock:
        sock.connect(str(path))
        sock.sendall(line + b'{"op": "hello"}\n')
        reader = sock.makefile("rb")
        assert b"ProtocolError" in reader.readline()
        assert b'"socket":"robot"' in reader.readline()


def test_an_unknown_op_is_refused_by_name(connector, client_for) -> None:
    reply = client_for(connector.robot_endpoint).request({"op": "reset"})
    assert reply["error_type"] == "UnknownOp" and "robot.sock" in reply["error"]
    reply = client_for(connector.operator_endpoint).request({"op": "create", "class": "FeetechMotorsBus"})
    assert reply["error_type"] == "UnknownOp"


def test_an_oversized_line_is_refused_and_the_connection_closed(connector) -> None:
    path = connector.socket_dir / "robot.sock"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.connect(str(path))
        chunk = b"x" * (1 << 20)
        sent = 0
        try:
            while sent <= MAX_LINE_BYTES:
                sock.sendall(chunk)
                sent += len(chunk)
        except BrokenPipeError:
            pass
        reply = sock.makefile("rb").readline()
    assert b'"error_type":"ProtocolError"' in reply and b"longer than" in reply


def test_a_class_outside_the_allow_list_is_not_allowed(connector, client_for) -> None:
    reply = client_for(connector.robot_endpoint).request({"op": "create", "class": "subprocess.Popen", "args": [["sh"]]})
    assert reply["error_type"] == "NotAllowed" and "FeetechMotorsBus" in reply["error"]


def test_a_port_that_is_not_the_connector_endpoint_is_not_allowed(connector, client_for, motors) -> None:
    client = client_for(connector.robot_endpoint)
    reply = client.request(
        {"op": "create", "class": "FeetechMotorsBus", "kwargs": encode({"port": "/dev/ttyUSB7", "motors": motors})}
    )
    assert reply["error_type"] == "NotAllowed" and "connector endpoint" in reply["error"]


def test_an_unknown_arm_selector_is_refused(connector, client_for, motors) -> None:
    client = client_for(connector.robot_endpoint)
    port = connector.robot_endpoint + "?arm=left"
    reply = client.request({"op": "create", "class": "FeetechMotorsBus", "kwargs": encode({"port": port, "motors": motors})})
    assert reply["error_type"] == "KeyError" and "no arm 'left'" in reply["error"]


@pytest.mark.parametrize("name", ["__class__", "__dict__", "_comm_success", "port_handler", "setup_motor", "scan_port"])
def test_private_and_unlisted_names_are_not_allowed(connector, client_for, motors, name) -> None:
    # Reads of unlisted public names get introspection's answer (test_connector_introspection.py).
    client = client_for(connector.robot_endpoint)
    object_id = client.create("FeetechMotorsBus", port=connector.robot_endpoint, motors=motors)
    requests = [
        {"op": "call", "object_id": object_id, "method": name},
        {"op": "setattr", "object_id": object_id, "name": name, "value": 1},
    ]
    if name.startswith("_"):
        requests.append({"op": "getattr", "object_id": object_id, "name": name})
    for request in requests:
        assert client.request(request)["error_type"] == "NotAllowed"


def test_getattr_on_a_method_answers_callable_and_on_a_field_its_value(connector, client_for, motors) -> None:
    client = client_for(connector.robot_endpoint)
    object_id = client.create("FeetechMotorsBus", port=connector.robot_endpoint, motors=motors)
    assert client.request({"op": "getattr", "object_id": object_id, "name": "sync_read"}) == {"ok": True, "callable": True}
    reply = client.request({"op": "getattr", "object_id": object_id, "name": "is_connected"})
    assert reply == {"ok": True, "callable": False, "value": False}
    # The customer sees the port it passed, never the cell's device path.
    port = client.request({"op": "getattr", "object_id": object_id, "name": "port"})
    assert port["value"] == connector.robot_endpoint


def test_objects_belong_to_their_connection(connector, client_for, motors) -> None:
    first = client_for(connector.robot_endpoint)
    object_id = first.create("FeetechMotorsBus", port=connector.robot_endpoint, motors=motors)
    other = client_for(connector.robot_endpoint)
    reply = other.request({"op": "getattr", "object_id": object_id, "name": "is_connected"})
    assert reply["error_type"] == "UnknownObject"


def test_malformed_fields_are_protocol_errors(connector, client_for) -> None:
    client = client_for(connector.robot_endpoint)
    assert client.request({"op": "create", "class": "FeetechMotorsBus", "args": "x"})["error_type"] == "ProtocolError"
    assert client.request({"op": "getattr", "object_id": 7, "name": "x"})["error_type"] == "ProtocolError"
    tagged = {"op": "create", "class": "FeetechMotorsBus", "args": [{"__armnet__": "pickle", "data": ""}]}
    assert client.request(tagged)["error_type"] == "ProtocolError"


def test_a_client_that_disconnects_mid_line_leaves_the_connector_serving(connector, client_for) -> None:
    path = connector.socket_dir / "operator.sock"
    raw_exchange(path, b'{"op": "get_teleop"', read_reply=False)
    assert client_for(connector.operator_endpoint).request({"op": "should_stop"}) == {"ok": True, "stop": False}


def test_many_clients_at_once_each_get_their_own_replies(connector, client_for) -> None:
    errors: list[str] = []

    def worker(index: int) -> None:
        client = client_for(connector.operator_endpoint)
        for round_ in range(20):
            reply = client.request({"op": "rollout_begin", "index": index * 100 + round_})
            if reply != {"ok": True}:
                errors.append(repr(reply))

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(24)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert errors == []
    assert len(connector.cell.rollouts) == 24 * 20
    assert connector.counters.connections >= 24


def test_stop_removes_the_sockets(make_connector, cell_config, socket_dir) -> None:
    connector = make_connector(cell_config(None))
    assert (socket_dir / "robot.sock").exists()
    connector.stop()
    assert not (socket_dir / "robot.sock").exists() and not (socket_dir / "operator.sock").exists()
