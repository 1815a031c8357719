"""The cell's flight recorder of a job, on a real connector, LeRobot's bus and the simulator:
the servo trace (Parquet) and each camera's video (MP4) in the cell's record directory."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import av
import numpy as np
import pyarrow.parquet as pq
import pytest
from armnet_connector import Connector, ConnectorConfig, LocalOperatorInputs, camera_video
from armnet_runtime import Cell
from armnet_runtime.lerobot.remote_camera import RemoteOpenCVCamera
from armnet_sim import SimulatedCellProcess


@pytest.fixture(autouse=True)
def roomy_video_queue(monkeypatch: pytest.MonkeyPatch) -> None:
    """The encoder's queue holds every frame here: what the video keeps must not hang on the machine's load."""
    monkeypatch.setattr(camera_video, "QUEUE_SIZE", 1000)


@pytest.fixture
def inputs() -> LocalOperatorInputs:
    """The person at the cell confirms each reset as it is asked for."""
    return LocalOperatorInputs(on_reset_requested=lambda inputs: inputs.confirm_reset())


@pytest.fixture
def record(tmp_path: Path) -> Path:
    return tmp_path / "record"


@pytest.fixture
def connector(sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
              cell_config: Callable[..., ConnectorConfig], inputs: LocalOperatorInputs, record: Path) -> Connector:
    """The clamp policy (a long step is clamped, not refused), keeping the cell's record of the job."""
    return make_connector(cell_config(sim_cell, safetyPolicy="clamp"), inputs=inputs, record_dir=record)


@pytest.fixture
def camera(connector: Connector, monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    from lerobot.cameras.opencv import OpenCVCameraConfig

    monkeypatch.setenv("ARMNET_CELL_SOCKET", connector.robot_endpoint)
    camera = RemoteOpenCVCamera(OpenCVCameraConfig(index_or_path="front", fps=30, width=640, height=480))
    camera.connect(warmup=False)
    yield camera
    if camera.is_connected:
        camera.disconnect()


def trace_rows(record: Path) -> list[dict[str, Any]]:
    return pq.read_table(record / "servo-trace").to_pylist()


def test_the_trace_holds_what_the_job_read_and_wrote_and_what_the_connector_did(
    connector: Connector, bus: Any, inputs: LocalOperatorInputs, record: Path,
) -> None:
    cell = Cell(robot_port=connector.robot_endpoint, operator_call_endpoint=connector.operator_endpoint)
    began = time.time()
    present = bus.sync_read("Present_Position")
    cell.rollout_begin(index=3, total=5)
    small = {"elbow_flex": present["elbow_flex"] + 2.0}
    bus.sync_write("Goal_Position", small)
    far = {"shoulder_pan": present["shoulder_pan"] + 80.0}  # past the cell's 30° step: clamped
    bus.sync_write("Goal_Position", far)
    cell.rollout_end()
    cell.reset()
    connector.cancel("the test cancelled the job")
    bus.disconnect(disable_torque=False)
    connector.stop()

    rows = trace_rows(record)
    assert connector.counters.trace_rows_written == len(rows) and connector.counters.trace_rows_dropped == 0
    assert all(row["time"].timestamp() >= began - 1 for row in rows)
    reads = [r for r in rows if r["kind"] == "present_position"]
    assert {r["motor"] for r in reads} >= set(present) and {r["arm"] for r in reads} == {"arm"}
    first = {r["motor"]: r["value"] for r in reads[: len(present)]}
    assert first == pytest.approx(present) and reads[0]["units"] == "normalized"
    goals = [(r["motor"], r["value"]) for r in rows if r["kind"] == "goal_position"]
    assert goals[0] == ("elbow_flex", pytest.approx(small["elbow_flex"]))
    # The goal the arm got is the clamped one, and the clamp says so.
    [clamp] = [r for r in rows if r["kind"] == "clamp"]
    assert (clamp["motor"], clamp["arm"], clamp["units"]) == ("shoulder_pan", "arm", "normalized")
    assert goals[1] == ("shoulder_pan", pytest.approx(clamp["value"]))
    assert abs(clamp["value"] - present["shoulder_pan"]) <= 30.0 + 1e-6
    kinds = [r["kind"] for r in rows if r["kind"] not in ("present_position", "goal_position")]
    assert kinds[:6] == ["rollout_begin", "clamp", "rollout_end", "reset_begin", "reset_end", "interlock_trip"]
    begin = next(r for r in rows if r["kind"] == "rollout_begin")
    assert (begin["rollout"], begin["detail"]) == (3, "of 5")
    assert next(r for r in rows if r["kind"] == "reset_end")["detail"] == "confirmed by the operator"
    assert "the test cancelled the job" in next(r for r in rows if r["kind"] == "interlock_trip")["detail"]
    assert not list((record / "servo-trace").glob(".*"))  # nothing half-written left


def test_an_operator_verdict_and_a_refused_goal_are_in_the_trace(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig], inputs: LocalOperatorInputs, motors: dict[str, Any],
    calibration: dict[str, Any], tmp_path: Path,
) -> None:
    from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

    record = tmp_path / "trip"
    connector = make_connector(cell_config(sim_cell, safetyPolicy="trip"), inputs=inputs, record_dir=record)
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    bus.connect()
    present = bus.sync_read("Present_Position")
    cell = Cell(robot_port=connector.robot_endpoint, operator_call_endpoint=connector.operator_endpoint)
    cell.rollout_begin(index=1, total=1)
    inputs.report_outcome(True)
    assert cell.is_complete() == (True, True)
    with pytest.raises(Exception, match="SafetyViolation|safety"):
        bus.sync_write("Goal_Position", {"wrist_flex": present["wrist_flex"] + 80.0})
    bus.disconnect(disable_torque=False)
    connector.stop()

    rows = trace_rows(record)
    [verdict] = [r for r in rows if r["kind"] == "operator_verdict"]
    assert verdict["detail"] == "success"
    [refusal] = [r for r in rows if r["kind"] == "refusal"]
    assert (refusal["arm"], refusal["motor"]) == ("arm", "wrist_flex") and refusal["detail"].startswith("relative")
    trip = next(r for r in rows if r["kind"] == "interlock_trip")
    assert trip["detail"].startswith("safety") and trip["time"] <= refusal["time"]  # it tripped, so refused
    assert not [r for r in rows if r["kind"] == "goal_position"]  # the refused goal never reached the arm


def test_each_camera_the_job_used_is_kept_as_a_video_that_plays(
    connector: Connector, camera: Any, bus: Any, record: Path,
) -> None:
    present = bus.sync_read("Present_Position")
    began, began_at = time.monotonic(), time.time() - 5  # the camera was connected a moment before
    frames = 0
    while time.monotonic() - began < 2.0:  # the arm moves: each frame is a new picture
        wiggle = 3.0 * np.sin((time.monotonic() - began) * 6)
        bus.sync_write("Goal_Position", {"shoulder_pan": present["shoulder_pan"] + wiggle})
        camera.async_read(timeout_ms=2000)
        frames += 1
        time.sleep(0.02)
    camera.disconnect()
    bus.disconnect(disable_torque=False)
    connector.stop()

    assert sorted(p.name for p in (record / "videos").iterdir()) == ["front.json", "front.mp4"]
    video = record / "videos" / "front.mp4"
    info = json.loads((record / "videos" / "front.json").read_text())
    assert info["camera"] == "front" and (info["width"], info["height"]) == (640, 480)
    assert began_at <= info["firstFrameAt"] <= time.time()
    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        decoded = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
        assert stream.codec_context.name == "h264"
    kept = connector.counters.video_frames_written
    assert len(decoded) == kept and connector.counters.video_frames_dropped == 0
    # At most 15 frames a second of a 30 fps camera, for the ~2 s the job held it.
    assert 15 <= kept <= 15 * 3.5, kept
    assert decoded[0].shape == (480, 640, 3)
    assert any(not np.array_equal(decoded[0], later) for later in decoded[1:])  # the arm moved in the video


def test_a_connector_without_a_record_directory_keeps_no_record(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig],
) -> None:
    plain = make_connector(cell_config(sim_cell))
    assert plain.cell.servo_trace is None and plain.cell.camera_video is None
    assert plain.cell.guard.recorder.trace is None and plain.interlock.on_trip is None


def test_the_host_reads_what_the_record_kept_and_dropped(connector: Connector, bus: Any) -> None:
    bus.sync_read("Present_Position")
    bus.disconnect(disable_torque=False)
    connector.stop()
    counts = connector.cell_record_counts()
    # One read of six motors, and the stop's own latch of the interlock: where the job's record ends.
    assert counts["trace_rows"] == {"kept": 7, "dropped": 0}
    assert trace_rows(connector.cell.servo_trace.directory.parent)[-1]["kind"] == "job_end"  # type: ignore[union-attr]
    assert counts["video_frames"] == {"kept": 0, "dropped": 0}
    assert set(counts) == {"trace_rows", "video_frames", "rollout_pictures"}
