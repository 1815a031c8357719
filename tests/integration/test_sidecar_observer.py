"""A pod job's connector seen by the agent through its observer socket (the path of ``--launcher pod``).

The real connector on the simulated SO-101 serves ``observer.sock`` in a
directory apart from the job's sockets (in a pod: a volume of the sidecar
only); the agent's ``SidecarObserver`` reads it, and the same ``JobSource``,
``CellTelemetry`` and ``RolloutRecorder`` as for a connector in the agent's
process turn it into NATS telemetry (a real nats-server) and the rollout
history. The job side is the customer's real SDK classes over ``robot.sock``
and the operator socket's ``rollout_begin``/``rollout_end``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator

import cv2
import numpy as np
import pytest
from armnet_launch.cell_spec import CameraSpec
from armnet_node.metrics import AgentMetrics
from armnet_node.rollout_history import Outcome, as_status, from_status
from armnet_node.rollout_recorder import RolloutRecorder
from armnet_node.sidecar_observer import SidecarObserver
from armnet_node.streams import NatsLink
from armnet_node.telemetry import CellTelemetry, TelemetrySettings
from armnet_node.telemetry_sources import JobSource
from armnet_runtime.lerobot.remote_camera import RemoteOpenCVCamera
from armnet_sim import SimulatedCellProcess

from tests.support.sidecar_pod import Pod
from tests.support.sim_connector import (
    heard,
    job_bus,
    request,
)

pytestmark = pytest.mark.integration


@pytest.fixture
def pod(sim: SimulatedCellProcess, monkeypatch: pytest.MonkeyPatch) -> Iterator[Pod]:
    pod = Pod(sim)
    monkeypatch.setenv("ARMNET_CELL_SOCKET", pod.connector.robot_endpoint)
    yield pod
    pod.close()


def test_a_pod_jobs_reads_and_camera_reach_nats_through_the_observer_socket(
        pod: Pod, link: NatsLink, nats_server: str) -> None:
    from lerobot.cameras.opencv import OpenCVCameraConfig

    bus = job_bus(pod.connector.robot_endpoint)
    bus.connect()
    camera = RemoteOpenCVCamera(OpenCVCameraConfig(index_or_path="front", fps=30, width=640, height=480))
    camera.connect(warmup=False)
    metrics = AgentMetrics()
    observer = SidecarObserver(lambda: pod.observer_path, metrics)
    try:
        camera.async_read(timeout_ms=2000)
        held = bus.sync_read("Present_Position", normalize=False)  # the job's own read
        # No simulator handed to the source: the frame can only be the job's camera, via the observer.
        source = JobSource(observer, (CameraSpec("front"),), sim=None)
        telemetry = CellTelemetry("cell-1", lambda: source, link, metrics, TelemetrySettings(servo_hz=4, frame_fps=2))
        got = heard(nats_server, ["telemetry.cell-1.servos", "telemetry.cell-1.camera.front"],
                    lambda: telemetry.tick(time.monotonic()))
    finally:
        observer.close()
        camera.disconnect()
        bus.disconnect(disable_torque=False)

    reading = json.loads(got["telemetry.cell-1.servos"])
    assert reading["source"] == "job"
    assert {m: v["position"] for m, v in reading["arms"]["arm"]["motors"].items()} == held
    image = cv2.imdecode(np.frombuffer(got["telemetry.cell-1.camera.front"], np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape == (240, 320, 3)
    assert metrics.registry.get_sample_value("armnet_agent_sidecar_observer_requests_total", {"result": "ok"}) >= 2


def test_a_pod_jobs_rollouts_are_recorded_from_the_observer_socket(pod: Pod) -> None:
    observer = SidecarObserver(lambda: pod.observer_path, AgentMetrics())
    recorder = RolloutRecorder(observer.rollout_events)
    try:
        pod.operator_op("rollout_begin", index=0, total=2, outcome_controls=True)
        pod.operator_op("rollout_end")
        recorder.sync()
        pod.operator_op("rollout_begin", index=1, total=2, outcome_controls=False)
        recorder.sync()
    finally:
        observer.close()
    first, second = recorder.history
    assert (first.index, first.total, first.outcome_controls, first.open) == (0, 2, True, False)
    assert (second.index, second.outcome_controls, second.open, second.outcome) == (1, False, True, Outcome.UNMARKED)


def test_a_restarted_agent_does_not_record_the_sidecars_earlier_rollouts_twice(pod: Pod) -> None:
    pod.operator_op("rollout_begin", index=0, total=3, outcome_controls=True)
    pod.operator_op("rollout_end")
    first_agent = SidecarObserver(lambda: pod.observer_path, AgentMetrics())
    before = RolloutRecorder(first_agent.rollout_events)
    before.sync()
    first_agent.close()
    written = as_status(before.history)  # what the first agent wrote to status.rollouts

    pod.operator_op("rollout_begin", index=1, total=3, outcome_controls=True)
    second_agent = SidecarObserver(lambda: pod.observer_path, AgentMetrics())
    after = RolloutRecorder(second_agent.rollout_events, history=from_status(written))
    after.sync()
    second_agent.close()
    assert [(e.index, e.open) for e in after.history] == [(0, False), (1, True)]


def test_the_observer_finds_a_restarted_sidecars_socket_again(pod: Pod) -> None:
    metrics = AgentMetrics()
    observer = SidecarObserver(lambda: pod.observer_path, metrics, retry_s=0.0)
    try:
        assert observer.servos() is not None
        pod.restart()
        first_try = observer.servos()  # the old connection is gone: counted, then reconnected
        again = observer.servos()
    finally:
        observer.close()
    assert first_try is None
    assert again == {"arm": "the job has not connected this arm's bus"}
    assert metrics.registry.get_sample_value("armnet_agent_sidecar_observer_requests_total",
                                             {"result": "failed"}) == 1


def test_the_observer_socket_changes_nothing(pod: Pod) -> None:
    for op in ({"op": "rollout_begin", "index": 7, "total": 9}, {"op": "reset"}, {"op": "call"}):
        refused = request(pod.observer_path, op)
        assert refused["ok"] is False and refused["error_type"] == "UnknownOp"
    assert list(pod.connector.cell.rollouts) == []
    assert pod.connector.cell.counters.resets == 0


def test_the_jobs_sockets_serve_no_observer_op_so_a_job_cannot_pose_as_the_observer(pod: Pod) -> None:
    # What the tenant's container can reach (the sockets volume): neither socket answers the observer's ops,
    # and the observer socket is not in it.
    assert sorted(p.name for p in pod.sockets.iterdir() if p.is_socket()) == ["operator.sock", "robot.sock"]
    for name in ("robot.sock", "operator.sock"):
        reply = request(pod.sockets / name, {"op": "rollouts"})
        assert reply["ok"] is False and reply["error_type"] == "UnknownOp"


def test_the_sidecars_final_record_carries_the_monitors_verdict_on_the_last_rollout(pod: Pod) -> None:
    """The monitor records its verdict on the last rollout at its end, and the job exits right after: the agent
    reads that verdict from the sidecar's final record (the chart's evaluation lost it before)."""
    from armnet_connector.cell import RolloutEvent
    from armnet_launch.sidecar import connector_record, parse_record, record_line
    from armnet_node.launchers import record_events

    pod.operator_op("rollout_begin", index=1, total=1, outcome_controls=False)
    begun = pod.connector.cell.rollouts[-1].at
    pod.connector.cell.record_rollout(RolloutEvent("verdict", begun + 0.001, index=1, success=False, score=0.125,
                                                   frame_at=time.time()))  # what the monitor appends at the end
    pod.operator_op("rollout_end")
    record = parse_record(record_line(connector_record(pod.connector)))
    assert record is not None
    recorder = RolloutRecorder(lambda: record_events(record))
    recorder.sync()

    [rollout] = as_status(recorder.history)
    assert (rollout["index"], rollout["outcome"], rollout["markedBy"]) == (1, "failure", "monitor")
    assert rollout["monitor"]["score"] == 0.125 and "endedAt" in rollout
