"""Cell telemetry end to end: the real connector on the simulated SO-101, the agent's NATS link, a real nats-server.

While a job runs, nothing is sent on the job's bus: the readings are what the
job's own reads left in its connector (positions only) and its camera's latest
capture. While the cell is idle the agent reads the servos itself, through one
port handle per arm that it keeps open. A subscriber on the FMS's side decodes
what arrives: JPEG of the published size, and servo values the simulated servos hold.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from armnet_connector import Connector, LocalOperatorInputs
from armnet_connector.reply_window import LATE_REPLY_WAIT_S
from armnet_connector.telemetry import ArmReader
from armnet_core.api import CELLS, GROUP, VERSION
from armnet_launch.cell_spec import CameraSpec
from armnet_node.bus_turns import BusTurns
from armnet_node.metrics import AgentMetrics
from armnet_node.streams import NatsLink
from armnet_node.telemetry import CellTelemetry, TelemetrySettings, TelemetrySource
from armnet_node.telemetry_sources import (
    ArmPort,
    IdleArms,
    IdleCameras,
    IdleSource,
    InProcessView,
    JobSource,
)
from armnet_runtime.lerobot.remote_camera import RemoteOpenCVCamera
from armnet_sim import SimulatedCellProcess

from tests.support.sim_connector import (
    CALIBRATION,
    MOTORS,
    cell_config,
    heard,
    job_bus,
)

pytestmark = pytest.mark.integration


@pytest.fixture
def connector(sim: SimulatedCellProcess, monkeypatch: pytest.MonkeyPatch) -> Iterator[Connector]:
    socket_dir = Path(tempfile.mkdtemp(prefix="ant-", dir="/tmp"))
    connector = Connector(cell_config(sim), socket_dir, inputs=LocalOperatorInputs()).start()
    monkeypatch.setenv("ARMNET_CELL_SOCKET", connector.robot_endpoint)
    yield connector
    connector.stop()
    shutil.rmtree(socket_dir, ignore_errors=True)


def publisher(source: TelemetrySource, link: NatsLink, metrics: AgentMetrics) -> CellTelemetry:
    return CellTelemetry("cell-1", lambda: source, link, metrics, TelemetrySettings(servo_hz=4, frame_fps=2))


def counted(metrics: AgentMetrics, name: str, result: str) -> float:
    return metrics.registry.get_sample_value(name, {"result": result}) or 0.0


def idle_source(sim: SimulatedCellProcess, cameras: tuple[CameraSpec, ...] = (), *, held: bool = False,
                handles: IdleArms | None = None, motor_model: str | None = "sts3215") -> IdleSource:
    return IdleSource({"arm": ArmPort(sim.arm.port, CALIBRATION, motor_model)}, cameras, BusTurns(),
                      lambda: held, None, IdleCameras(), handles or IdleArms())


def test_during_a_job_frames_and_the_jobs_own_position_reads_come_through_its_connector(
        connector: Connector, sim: SimulatedCellProcess, link: NatsLink, nats_server: str) -> None:
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
        source = JobSource(InProcessView(connector.cell), (CameraSpec("front"),), sim=None)
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
    assert {m: v["position"] for m, v in motors.items()} == held
    assert counted(metrics, "armnet_agent_telemetry_frames_total", "published") == 1


def test_during_a_job_telemetry_sends_nothing_on_its_bus_so_load_and_temperature_are_absent(
        connector: Connector, sim: SimulatedCellProcess) -> None:
    bus = job_bus(connector.robot_endpoint)
    bus.connect()
    try:
        held = bus.sync_read("Present_Position", normalize=False)
        bus.write("Torque_Enable", "gripper", 0, normalize=False)
        moved = int(held["gripper"]) + 200
        sim.arm.move_by_hand("gripper", moved)  # the servo moves; the job has not read it since
        readings = JobSource(InProcessView(connector.cell), (), sim=None).servos()
        assert sim.arm.positions()["gripper"] == pytest.approx(moved, abs=2)
    finally:
        bus.disconnect(disable_torque=False)
    assert readings is not None
    arm = readings["arm"]
    assert not isinstance(arm, str)
    gripper = arm["gripper"]
    assert gripper is not None
    assert gripper.position == held["gripper"]  # the job's read, not a fresh one of the bus
    assert gripper.load is None and gripper.temperature is None


def test_a_job_that_has_not_read_positions_yet_shows_why(connector: Connector) -> None:
    bus = job_bus(connector.robot_endpoint)
    bus.connect()
    try:
        readings = JobSource(InProcessView(connector.cell), (), sim=None).servos()
    finally:
        bus.disconnect(disable_torque=False)
    assert readings == {"arm": "the job has not read Present_Position yet"}


def test_a_stopping_connector_shows_nothing(connector: Connector) -> None:
    connector.cell.stopping.set()
    try:
        assert JobSource(InProcessView(connector.cell), (), sim=None).servos() is None
    finally:
        connector.cell.stopping.clear()


def test_an_idle_cell_is_read_by_the_agent_and_a_failing_camera_stops_nothing_else(
        sim: SimulatedCellProcess, link: NatsLink, nats_server: str) -> None:
    metrics = AgentMetrics()
    source = idle_source(sim, (CameraSpec("front", index_or_path="/dev/armnet-no-camera"),))
    telemetry = publisher(source, link, metrics)
    # A servo whose reply the loaded host lost shows as no sample (the page shows a gap), a read
    # that got nothing is skipped; the next tick reads again. What is checked is a full reading
    # and the failing camera beside it, on every tick.
    ticks, reading = ticks_until_a_full_reading(nats_server, telemetry, metrics)
    assert reading["source"] == "idle"
    assert set(reading["arms"]["arm"]["motors"]) == set(MOTORS)
    assert all(0 <= v["position"] < 4096 for v in reading["arms"]["arm"]["motors"].values())
    assert {v["temperature"] for v in reading["arms"]["arm"]["motors"].values()} == {28}
    assert counted(metrics, "armnet_agent_telemetry_frames_total", "failed") == ticks
    assert (counted(metrics, "armnet_agent_telemetry_servo_reads_total", "published")
            + counted(metrics, "armnet_agent_telemetry_servo_reads_total", "skipped")) == ticks


def ticks_until_a_full_reading(nats_server: str, telemetry: CellTelemetry, metrics: AgentMetrics,
                               most: int = 8) -> tuple[int, dict[str, Any]]:
    """Tick (0.6 s apart: both cadences due every time) until a reading with every servo arrives."""

    async def body() -> tuple[int, dict[str, Any]]:
        import nats

        client = await nats.connect(nats_server)
        try:
            sub = await client.subscribe("telemetry.cell-1.servos")
            await client.flush()
            for tick in range(1, most + 1):
                published = counted(metrics, "armnet_agent_telemetry_servo_reads_total", "published")
                await asyncio.to_thread(telemetry.tick, time.monotonic())
                if counted(metrics, "armnet_agent_telemetry_servo_reads_total", "published") > published:
                    reading: dict[str, Any] = json.loads((await sub.next_msg(timeout=10)).data)
                    if all(v is not None for v in reading["arms"]["arm"]["motors"].values()):
                        return tick, reading
                await asyncio.sleep(0.6)
            raise AssertionError(f"no full servo reading in {most} ticks")
        finally:
            await client.close()

    return asyncio.run(asyncio.wait_for(body(), 120))


def test_an_idle_arms_port_stays_open_between_reads_and_closes_on_request(sim: SimulatedCellProcess) -> None:
    handles = IdleArms()
    source = idle_source(sim, handles=handles)
    first, second = source.servos(), source.servos()
    assert first is not None and second is not None
    assert set(first["arm"]) == set(second["arm"]) == set(MOTORS)
    reader = handles.readers[0]
    assert reader.is_open
    handles.close()
    assert not reader.is_open


def test_the_read_after_a_cut_short_idle_read_answers_with_every_servo(sim: SimulatedCellProcess) -> None:
    source = idle_source(sim)
    sim.arm.drop_replies("elbow_flex", 1)  # the sync read stops there; the later servos' replies arrive late
    try:
        cut = source.servos()
        time.sleep(0.05)
        after = source.servos()
        for _ in range(20):  # a miss of its own (a host starving the simulator past a window) is read again
            arm = (after or {}).get("arm")
            if arm is None or isinstance(arm, str) or None not in arm.values():
                break
            after = source.servos()
    finally:
        sim.arm.clear_faults()
    assert cut is not None and after is not None
    cut_arm, after_arm = cut["arm"], after["arm"]
    assert not isinstance(cut_arm, str) and not isinstance(after_arm, str)
    assert cut_arm["elbow_flex"] is None
    positions = sim.arm.positions()
    assert all(sample is not None for sample in after_arm.values())
    assert {m: s.position for m, s in after_arm.items() if s is not None} == pytest.approx(positions, abs=3)


def read_whole(reader: ArmReader, ids: range, attempts: int = 20) -> dict[int, Any]:
    """The first read in which every servo answered: a loaded host can starve the simulator past
    a reply's 50 ms window now and then (a miss the reader reports as None, not this test's subject)."""
    for _ in range(attempts):
        got = reader.read(ids)
        if None not in got.values():
            return got
    raise AssertionError(f"no read answered by every servo in {attempts} tries: {got}")


def test_a_read_soon_after_a_cut_short_one_first_waits_past_the_reply_window(sim: SimulatedCellProcess) -> None:
    waits: list[float] = []
    reader = ArmReader(sim.arm.port, 0, sleep=lambda s: (waits.append(s), time.sleep(s)) and None)
    ids = range(1, 7)
    try:
        read_whole(reader, ids)
        waits.clear()
        sim.arm.drop_replies("elbow_flex", 1)
        cut = reader.read(ids)
        assert not waits  # a read after a whole one does not wait
        after = reader.read(ids)
        assert len(waits) == 1 and 0 < waits[0] <= LATE_REPLY_WAIT_S  # the read after the cut one waited
        settled = read_whole(reader, ids)
    finally:
        sim.arm.clear_faults()
        reader.close()
    assert cut[3] is None
    # The cut read's late reply was waited out, not taken as this read's answer: each value it has
    # is its own servo's (a shifted reply would put one servo's position under another's id).
    by_id = {sim.arm.motors[name].id: position for name, position in sim.arm.positions().items()}
    assert {i: s.position for i, s in after.items() if s is not None} == pytest.approx(
        {i: by_id[i] for i, s in after.items() if s is not None}, abs=3)
    assert {i: s.position for i, s in settled.items() if s is not None} == pytest.approx(by_id, abs=3)


def test_an_idle_arm_of_a_non_feetech_motor_model_is_not_read_and_says_why(sim: SimulatedCellProcess) -> None:
    readings = idle_source(sim, motor_model="xl330-m077").servos()
    assert readings is not None
    assert "no Feetech servo" in str(readings["arm"])


def test_an_idle_simulated_cell_shows_its_simulator_drawn_at_the_published_size(sim: SimulatedCellProcess) -> None:
    source = IdleSource({}, (CameraSpec("front", width=640, height=480),), BusTurns(), lambda: False, sim,
                        IdleCameras(), IdleArms())
    frame = source.frames()["front"]
    assert not isinstance(frame, str) and frame.image.shape == (240, 320, 3)


def test_nothing_is_read_while_a_job_holds_the_bus(sim: SimulatedCellProcess) -> None:
    assert idle_source(sim, held=True).servos() is None


def test_a_failing_camera_is_not_reopened_before_its_backoff() -> None:
    now = [100.0]
    cameras = IdleCameras(clock=lambda: now[0])
    spec = (CameraSpec("front", index_or_path="/dev/armnet-no-camera"),)
    first = cameras.frames(spec)["front"]
    again = cameras.frames(spec)["front"]
    now[0] += 1.5
    retried = cameras.frames(spec)["front"]
    assert isinstance(first, str) and "retried in" not in first
    assert again == "failed 1 time(s) in a row; retried in 1 s"
    assert isinstance(retried, str) and "retried in" not in retried


def test_a_changed_camera_of_the_cell_is_tried_at_once_not_after_the_old_ones_backoff() -> None:
    cameras = IdleCameras(clock=lambda: 100.0)
    old = (CameraSpec("front", index_or_path="/dev/armnet-no-camera"),)
    new = (CameraSpec("front", index_or_path="/dev/armnet-other-camera"),)
    cameras.frames(old)
    tried = cameras.frames(new)["front"]
    assert isinstance(tried, str) and "retried in" not in tried and "armnet-other-camera" in tried


def test_camera_reads_take_no_bus_turn(sim: SimulatedCellProcess) -> None:
    import threading

    turns = BusTurns()
    source = IdleSource({}, (CameraSpec("front", index_or_path="/dev/armnet-no-camera"),), turns, lambda: False,
                        None, IdleCameras(), IdleArms())
    entered, release = threading.Event(), threading.Event()

    def launch() -> None:
        with turns.launching():
            entered.set()
            release.wait(10)

    thread = threading.Thread(target=launch)
    thread.start()
    try:
        assert entered.wait(5)
        started = time.monotonic()
        frames = source.frames()  # a launch holds the bus: the camera is still tried, not queued behind it
        elapsed = time.monotonic() - started
    finally:
        release.set()
        thread.join()
    assert isinstance(frames["front"], str) and elapsed < 5


def test_a_launch_closing_cameras_waits_only_its_bound_for_a_read_under_way() -> None:
    import threading

    cameras = IdleCameras()
    started = time.monotonic()
    holder = threading.Thread(target=lambda: cameras.frames((), wait_s=0))
    with cameras._lock:  # a read under way (a hung device)
        holder.start()
        closed = cameras.close(wait_s=0.2)
    holder.join()
    assert not closed and time.monotonic() - started < 2
    assert cameras.suspended and cameras.frames((CameraSpec("front", index_or_path=0),)) == {}


def test_the_telemetry_thread_ends_on_stop_and_closes_its_devices(
        sim: SimulatedCellProcess, link: NatsLink) -> None:
    handles, cameras = IdleArms(), IdleCameras()
    source = IdleSource({"arm": ArmPort(sim.arm.port, CALIBRATION)}, (), BusTurns(), lambda: False, None,
                        cameras, handles)

    def close() -> None:
        cameras.close(wait_s=0)
        handles.close()

    telemetry = CellTelemetry("cell-1", lambda: source, link, AgentMetrics(), TelemetrySettings(servo_hz=20),
                              on_exit=close).start()
    deadline = time.monotonic() + 15  # the reader is listed before its port opens; a loaded host is slow
    while not (handles.readers and handles.readers[0].is_open) and time.monotonic() < deadline:
        time.sleep(0.02)
    reader = handles.readers[0]
    assert reader.is_open
    telemetry.stop()
    assert telemetry.join(5)
    assert not reader.is_open and cameras.suspended


def test_a_stopped_cell_worker_ends_its_telemetry_thread(k8s: Any, link: NatsLink, nats_server: str) -> None:
    """A Cell removed from the node (or the agent stopping) stops its worker: its telemetry ends with it."""
    import uuid

    from armnet_node.kube import AgentKube
    from armnet_node.model import parse_cell
    from armnet_node.plan import HostPaths
    from armnet_node.runner import RunnerDeps
    from armnet_node.worker import CellWorker, WorkerSettings
    from kubernetes import client

    from tests.support.fms_objects import a_cell, apply

    name = f"telemetry-{uuid.uuid4().hex[:8]}"
    cell = parse_cell(apply(k8s, a_cell(name)))
    state_dir = Path(tempfile.mkdtemp(prefix="ant-", dir="/tmp"))
    deps = RunnerDeps(kube=AgentKube(k8s.api_client()), launcher=None,  # type: ignore[arg-type]  # no job here
                      paths=HostPaths(state_dir), metrics=AgentMetrics(), link=link, uploads=None)
    worker = CellWorker(cell, deps, WorkerSettings(heartbeat_period=5, telemetry=TelemetrySettings(servo_hz=10)))
    try:
        got = heard(nats_server, [f"telemetry.{name}.servos"], worker.start)
        assert json.loads(got[f"telemetry.{name}.servos"])["source"] == "idle"
    finally:
        worker.stop()
        shutil.rmtree(state_dir, ignore_errors=True)
        client.CustomObjectsApi(k8s.api_client()).delete_cluster_custom_object(GROUP, VERSION, CELLS, name)
    telemetry = worker.telemetry
    assert telemetry is not None and telemetry.join(5)
