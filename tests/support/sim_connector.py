"""A real connector's cell on the simulated SO-101 and a NATS listener, for the telemetry integration tests."""

from __future__ import annotations

import asyncio
import json
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from importlib import resources
from pathlib import Path
from typing import Any

from armnet_connector import ConnectorConfig
from armnet_node.sidecar_socket import connect_long
from armnet_node.streams import NatsLink, StreamSettings
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus
from armnet_sim import SimulatedCellProcess

CALIBRATION = Path(str(resources.files("armnet_sim.data").joinpath("so101.json")))
MOTORS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")


def cell_config(sim: SimulatedCellProcess) -> ConnectorConfig:
    return ConnectorConfig.model_validate({
        "arms": {"arm": {"port": sim.arm.port, "calibrationFile": str(CALIBRATION), "robotId": "sim-so101"}},
        "cameras": {"front": {"indexOrPath": 0, "fps": 30, "width": 640, "height": 480}},
        "simulated": True,
    })


def job_bus(endpoint: str) -> RemoteFeetechMotorsBus:
    """The SO-101 bus a job builds, with the cell's calibration."""
    import json

    from lerobot.motors import Motor, MotorCalibration, MotorNormMode

    motors = {name: Motor(i + 1, "sts3215", MotorNormMode.DEGREES) for i, name in enumerate(MOTORS)}
    motors["gripper"] = Motor(6, "sts3215", MotorNormMode.RANGE_0_100)
    calibration = {name: MotorCalibration(**entry) for name, entry in json.loads(CALIBRATION.read_text()).items()}
    return RemoteFeetechMotorsBus(port=endpoint, motors=motors, calibration=calibration)


def heard(nats_url: str, subjects: list[str], publish: Any) -> dict[str, bytes]:
    """The first message on each subject after ``publish()`` ran (subscribed before it)."""

    async def body() -> dict[str, bytes]:
        import nats

        client = await nats.connect(nats_url)
        got: dict[str, bytes] = {}
        subs = [await client.subscribe(s) for s in subjects]
        await client.flush()
        await asyncio.to_thread(publish)
        for subject, sub in zip(subjects, subs, strict=True):
            got[subject] = (await sub.next_msg(timeout=10)).data
        await client.close()
        return got

    return asyncio.run(asyncio.wait_for(body(), 30))




@contextmanager
def simulated_so101() -> Iterator[SimulatedCellProcess]:
    cell = SimulatedCellProcess("so101").start()
    try:
        yield cell
    finally:
        cell.stop()


@contextmanager
def connected_link(nats_url: str) -> Iterator[NatsLink]:
    """The agent's NATS link, connected (within 20 s) before it is handed out."""
    link = NatsLink(StreamSettings(url=nats_url)).start()
    try:
        deadline = time.monotonic() + 20
        while not link.connected and time.monotonic() < deadline:
            time.sleep(0.05)
        assert link.connected, "the agent's NATS link did not connect"
        yield link
    finally:
        link.stop()


def request(path: Path, message: dict[str, Any]) -> dict[str, Any]:
    """One request line on a unix socket, as anyone who can reach the socket could send it."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
        conn.settimeout(5)
        connect_long(conn, path)
        conn.sendall(json.dumps(message).encode() + b"\n")
        data = b""
        while not data.endswith(b"\n"):
            chunk = conn.recv(1 << 16)
            if not chunk:
                break
            data += chunk
    reply: dict[str, Any] = json.loads(data)
    return reply
