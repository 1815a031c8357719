"""Cell telemetry end to end: the real connector on the simulated SO-101, the agent's NATS link, a real nats-server.

While a job runs, the readings go through the job's connector (its device locks,
its bus, its camera's latest capture); while the cell is idle the agent reads the
servos itself. A subscriber on the FMS's side decodes what arrives: JPEG of the
published size, and servo values the simulated servos hold.
"""

from __future__ import annotations

import asyncio
import shutil
import tempfile
import time
from collections.abc import Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from armnet_agent.connector import Connector, ConnectorConfig, LocalOperatorInputs
from armnet_agent.launch.cell_spec import CameraSpec
from armnet_agent.node.bus_turns import BusTurns
from armnet_agent.node.metrics import AgentMetrics
from armnet_agent.node.streams import NatsLink, StreamSettings
from armnet_agent.node.telemetry import CellTelemetry, TelemetrySettings, TelemetrySource
from armnet_agent.node.telemetry_sources import IdleCameras, IdleSource, JobSource
from armnet_agent.sim import SimulatedCellProcess
from armnet_runtime.lerobot.remote_camera import RemoteOpenCVCamera
from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

pytestmark = pytest.mark.integration

CALIBRATION = Path(str(resources.files("armnet_agent.sim.data").joinpath("so101.json")))
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


@pytest.fixture(scope="module")
def sim() -> Iterator[SimulatedCellProcess]:
    cell = SimulatedCellProcess("so101").start()
    yield cell
    cell.stop()


@pytest.fixture(scope="module")
def link(nats_server: str) -> Iterator[NatsLink]:
    link = NatsLink(StreamSettings(url=nats_server)).start()
    deadline = time.monotonic() + 20
    while not link.connected and time.monotonic() < deadline:
        time.sleep(0.05)
    assert link.connected, "the agent's NATS link did not connect"
    yield link
    link.stop()


@pytest.fixture
def connector(sim: SimulatedCellProcess, monkeypatch: pytest.MonkeyPatch) -> Iterator[Connector]:
    socket_dir = Path(tempfile.mkdtemp(prefix="ant-", dir="/tmp"))
    connector = Connector(cell_config(sim), socket_dir, inputs=LocalOperatorInputs()).start()
    monkeypatch.setenv("ARMNET_CELL_SOCKET", connector.robot_endpoint)
    yield connector
    connector.stop()
    shutil.rmtree(socket_dir, ignore_errors=True)


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


def publisher(source: TelemetrySource, link: NatsLink, metrics: AgentMetrics) -> CellTelemetry:
    return CellTelemetry("cell-1", lambda: source, link, metrics, TelemetrySettings(servo_hz=4, frame_fps=2))


def counted(metrics: AgentMetrics, name: str, result: str) -> float:
    return metrics.registry.get_sample_value(name, {"result": result}) or 0.0


def test_during_a_job_frames_and_servo_readings_come_through_its_connector(
        connector: Connector, link: NatsLink, nats_server: str) -> None:
    import json

    from lerobot.cameras.opencv import OpenCVCameraConfig

    bus = job_bus(connector.robot_endpoint)
    bus.connect()
    camera = RemoteOpenCVCamera(OpenCVCameraConfig(index_or_path="front", fps=30, width=640, height=480))
    camera.connect(warmup=False)
    try:
        camera.async_read(timeout_ms=2000)
        held = bus.sync_read("Present_Position", normalize=False)  # what the job itself reads
        metrics = AgentMetrics()
        source = JobSource(connector.cell, (CameraSpec("front"),), sim=None)
        telemetry = publisher(source, link, metrics)
        got = heard(nats_server, ["telemetry.cell-1.servos", "telemetry.cell-1.camera.front"],
                    lambda: telemetry.tick(time.monotonic()))
    finally:
        camera.disconnect()
        bus.disconnect(disable_torque=False)

    image = cv2.imdecode(np.frombuffer(got["telemetry.cell-1.camera.front"], np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape == (240, 320, 3)  # the 640x480 capture, scaled to 320 wide
    reading = json.loads(got["telemetry.cell-1.servos"])
    motors = reading["arms"]["arm"]["motors"]
    assert reading["source"] == "job"
    assert {m: v["position"] for m, v in motors.items()} == pytest.approx(held, abs=3)
    assert {v["temperature"] for v in motors.values()} == {28}  # the simulated STS3215's temperature
    assert counted(metrics, "armnet_agent_telemetry_frames_total", "published") == 1


def test_a_job_call_holding_the_device_makes_the_read_skip_instead_of_waiting(connector: Connector) -> None:
    import threading

    from armnet_agent.connector.telemetry import read_cell_servos

    lock = connector.cell.locks.get(connector.config.arms["arm"].port)
    held, done = threading.Event(), threading.Event()

    def job_call() -> None:  # another connection's call, on its own thread
        with lock:
            held.set()
            done.wait(10)

    thread = threading.Thread(target=job_call)
    thread.start()
    try:
        assert held.wait(5)
        readings = read_cell_servos(connector.cell, lock_wait_s=0.02)
    finally:
        done.set()
        thread.join()
    assert readings == {"arm": "busy"}


def test_an_idle_cell_is_read_by_the_agent_and_a_failing_camera_stops_nothing_else(
        sim: SimulatedCellProcess, link: NatsLink, nats_server: str) -> None:
    import json

    metrics = AgentMetrics()
    source = IdleSource(
        {"arm": (sim.arm.port, CALIBRATION)}, (CameraSpec("front", index_or_path="/dev/armnet-no-camera"),),
        BusTurns(), lambda: False, None, IdleCameras(),
    )
    telemetry = publisher(source, link, metrics)
    got = heard(nats_server, ["telemetry.cell-1.servos"], lambda: telemetry.tick(time.monotonic()))

    reading = json.loads(got["telemetry.cell-1.servos"])
    assert reading["source"] == "idle"
    assert set(reading["arms"]["arm"]["motors"]) == set(MOTORS)
    assert all(0 <= v["position"] < 4096 for v in reading["arms"]["arm"]["motors"].values())
    assert counted(metrics, "armnet_agent_telemetry_frames_total", "failed") == 1
    assert counted(metrics, "armnet_agent_telemetry_servo_reads_total", "published") == 1


def test_an_idle_simulated_cell_shows_its_simulator_drawn_at_the_published_size(sim: SimulatedCellProcess) -> None:
    source = IdleSource({}, (CameraSpec("front", width=640, height=480),), BusTurns(), lambda: False, sim,
                        IdleCameras())
    frame = source.frames()["front"]
    assert not isinstance(frame, str) and frame.image.shape == (240, 320, 3)


def test_nothing_is_read_while_a_job_holds_the_bus(sim: SimulatedCellProcess) -> None:
    source = IdleSource({"arm": (sim.arm.port, CALIBRATION)}, (), BusTurns(), lambda: True, None,
                        IdleCameras())
    assert source.servos() is None
