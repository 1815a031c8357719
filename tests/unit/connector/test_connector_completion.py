"""``ctx.cell.is_complete`` through the real connector on the simulated SO-101, scored from rendered frames.

The simulator's camera draws a red disc on the arm's end effector and a blue
target pad where the disc lands at ``TARGET_POSE``; the cell's completion
monitor looks for the disc inside the pad's region. LeRobot's bus (the SDK's
proxy) drives the arm; the SDK's ``Cell`` asks. The main cases run three times: with the
region scorer in the connector, with the service scorer asking a judge over HTTP, and
with the learned classifier the project trains on rendered frames.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from armnet_connector import CompletionConfig, Connector, ConnectorConfig
from armnet_connector.completion import build_scorer
from armnet_connector.hardware import simulated_camera_factory
from armnet_runtime.context import Cell
from armnet_sim import SimulatedCellProcess
from armnet_sim.render import TARGET_POSE, target_region
from armnet_sim.scene_samples import SHIPPED_CLASSIFIER, SHIPPED_CLASSIFIER_INPUT

from tests.support.scoring_service import ScoringService

pytestmark = pytest.mark.unit

STEP = 8.0  # degrees per goal write, under the cell's limit


def completion_of_the_target() -> dict[str, Any]:
    left, top, width, height = target_region(640, 480)
    return {
        "camera": "front",
        "region": {"left": left, "top": top, "width": width, "height": height},
        "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80},
        "consecutiveFrames": 3,
        "rateHz": 15,
    }


def region_judge(completion: dict[str, Any]) -> ScoringService:
    """A scoring service that judges each JPEG it is sent with the region scorer.

    It stands for an external judge (a VLM, a team's model): the frames cross HTTP as
    JPEG, and the verdict comes back as ``{"score": ...}``.
    """
    judge = build_scorer(CompletionConfig.model_validate(completion))

    def answer(_headers: dict[str, str], body: bytes) -> tuple[int, bytes]:
        import cv2

        verdict = judge.score(cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR))
        return 200, json.dumps({"score": 1.0 if verdict.hit else 0.0, "detail": verdict.detail}).encode()

    return ScoringService(answer)


@pytest.fixture
def connector(request: pytest.FixtureRequest, sim_cell: SimulatedCellProcess,
              make_connector: Callable[..., Connector], cell_config: Callable[..., ConnectorConfig]) -> Iterator[Connector]:
    """The cell's monitor with the region scorer, (``"service"``) a service that judges with it over HTTP,
    or (``"classifier"``) the learned classifier the project ships for its simulated cells."""
    completion = completion_of_the_target()
    if getattr(request, "param", "region") == "classifier":
        completion = {"camera": "front", "scorer": "classifier",
                      "classifier": {"model": str(SHIPPED_CLASSIFIER.resolve()), "inputSize": SHIPPED_CLASSIFIER_INPUT},
                      "consecutiveFrames": completion["consecutiveFrames"], "rateHz": completion["rateHz"]}
    if getattr(request, "param", "region") == "service":
        judge = region_judge(completion)
        request.addfinalizer(judge.close)
        completion = {"camera": "front", "scorer": "service", "service": {"url": judge.url, "timeoutSeconds": 1},
                      "consecutiveFrames": completion["consecutiveFrames"], "rateHz": completion["rateHz"]}
    config = cell_config(sim_cell, completion=completion)
    # ("record"): the region scorer, keeping the rollouts' pictures in a record directory.
    record = request.getfixturevalue("tmp_path") / "record" if getattr(request, "param", "") == "record" else None
    yield make_connector(config, camera_factory=simulated_camera_factory(source=sim_cell), record_dir=record)


# `bus` is the connector conftest's: LeRobot's bus through this module's `connector`.


def drive_to(bus: Any, goal: dict[str, float]) -> None:
    """Step every joint of ``goal`` towards it, then wait until the arm is there."""
    deadline = time.monotonic() + 60
    while True:
        present = bus.sync_read("Present_Position")
        if all(abs(present[j] - g) < 0.5 for j, g in goal.items()):
            return
        assert time.monotonic() < deadline, f"the arm did not reach {goal}: {present}"
        step = {j: present[j] + max(-STEP, min(STEP, g - present[j])) for j, g in goal.items()}
        bus.sync_write("Goal_Position", step)
        time.sleep(0.05)


def a_job_cell(connector: Connector) -> Cell:
    return Cell(robot_port=connector.robot_endpoint, operator_call_endpoint=connector.operator_endpoint)


@pytest.mark.parametrize("connector", ["region", "service", "classifier"], indirect=True)
def test_a_job_that_drives_the_arm_onto_the_target_is_scored_complete(connector: Connector, bus: Any) -> None:
    cell = a_job_cell(connector)
    assert not cell.is_complete(block=True)
    drive_to(bus, dict(TARGET_POSE))
    status = cell.is_complete(block=True)
    deadline = time.monotonic() + 30  # K frames in a row: the streak fills after the arm stops
    while not status.complete and time.monotonic() < deadline:
        status = cell.is_complete(block=True)
    assert (status.complete, status.success) == (True, True)
    assert connector.counters.completion_scorer_errors == 0
    assert connector.record().counters["completion_frames_scored"] >= 3


@pytest.mark.parametrize("connector", ["region", "service", "classifier"], indirect=True)
def test_a_job_that_stops_short_of_the_target_is_not_complete(connector: Connector, bus: Any) -> None:
    short = {**TARGET_POSE, "elbow_flex": TARGET_POSE["elbow_flex"] - 15.0}
    drive_to(bus, short)
    cell = a_job_cell(connector)
    for _ in range(5):  # five final checks, each on frames captured after the arm stopped
        assert cell.is_complete(block=True) == (False, False)
    assert connector.counters.completion_block_timeouts == 0


def test_an_operators_outcome_wins_over_the_monitor(connector: Connector, bus: Any) -> None:
    drive_to(bus, dict(TARGET_POSE))
    cell = a_job_cell(connector)
    deadline = time.monotonic() + 30
    while not cell.is_complete(block=True) and time.monotonic() < deadline:
        pass
    connector.cell.inputs.report_outcome(False)  # the operator says: failed
    assert tuple(cell.is_complete()) == (True, False)


def test_a_cell_without_completion_settings_never_completes_on_its_own(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig],
) -> None:
    plain = make_connector(cell_config(sim_cell), camera_factory=simulated_camera_factory(source=sim_cell))
    assert plain.monitor is None
    assert a_job_cell(plain).is_complete(block=True) == (False, False)


def a_rollout_onto_the_target(cell: Cell, bus: Any) -> None:
    """Rollout 1 of 2: the arm driven onto the target until the monitor says complete (K frames in a row)."""
    cell.rollout_begin(index=1, total=2)
    drive_to(bus, dict(TARGET_POSE))
    deadline = time.monotonic() + 30
    while not cell.is_complete(block=True) and time.monotonic() < deadline:
        pass


def verdicts(connector: Connector) -> list[Any]:
    return [e for e in connector.cell.rollouts if e.kind == "verdict"]


def test_the_monitor_s_complete_is_recorded_once_on_the_open_rollout_with_its_score(
    connector: Connector, bus: Any,
) -> None:
    cell = a_job_cell(connector)
    a_rollout_onto_the_target(cell, bus)
    assert cell.is_complete(block=True).complete  # asked again: still one verdict
    cell.rollout_end()

    [verdict] = verdicts(connector)
    assert (verdict.index, verdict.success) == (1, True)
    assert 0.0 < verdict.score <= 1.0 and verdict.frame_at is not None
    assert verdict.frame_at <= verdict.at  # the frame was scored before the job was told
    assert [e.kind for e in connector.cell.rollouts] == ["begin", "verdict", "end"]


@pytest.mark.parametrize("connector", ["record"], indirect=True)
def test_each_rollout_keeps_its_first_verdict_and_last_frame_in_the_cell_s_record(
    connector: Connector, bus: Any,
) -> None:
    import cv2

    cell = a_job_cell(connector)
    a_rollout_onto_the_target(cell, bus)
    cell.rollout_end()
    cell.rollout_begin(index=1, total=2)  # the index again: a folder of its own
    cell.rollout_end()
    deadline = time.monotonic() + 30  # written off the job's path, by the writer's thread
    while connector.counters.rollout_frames_kept < 6 and time.monotonic() < deadline:
        time.sleep(0.05)
    record = connector.cell.rollout_frames.directory  # type: ignore[union-attr]

    folders = sorted((record / "rollouts").iterdir())
    assert [f.name[:7] for f in folders] == ["000001-", "000001-"]
    assert sorted(p.name for p in folders[0].iterdir()) == ["first.jpg", "last.jpg", "verdict.jpg"], [sorted(p.name for p in f.iterdir()) for f in folders]
    verdict = cv2.imread(str(folders[0] / "verdict.jpg"))
    assert verdict is not None and verdict.shape == (480, 640, 3)
    # The picture the verdict rests on shows what the monitor saw: the disc on the pad.
    assert build_scorer(CompletionConfig.model_validate(completion_of_the_target())).score(verdict).hit
    assert connector.counters.rollout_frames_kept == 6 and connector.counters.rollout_frames_dropped == 0


def test_a_rollout_the_monitor_never_saw_complete_ends_judged_a_failure(connector: Connector, bus: Any) -> None:
    cell = a_job_cell(connector)
    drive_to(bus, {**TARGET_POSE, "elbow_flex": TARGET_POSE["elbow_flex"] - 15.0})
    cell.rollout_begin(index=1, total=1)
    assert cell.is_complete(block=True) == (False, False)
    cell.rollout_end()
    cell.rollout_end()  # no rollout open: no second verdict

    [verdict] = verdicts(connector)
    assert (verdict.index, verdict.success) == (1, False)


def test_no_verdict_is_recorded_outside_a_rollout_or_on_a_cell_without_a_monitor(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig], connector: Connector, bus: Any,
) -> None:
    drive_to(bus, dict(TARGET_POSE))
    cell = a_job_cell(connector)
    deadline = time.monotonic() + 30
    while not cell.is_complete(block=True) and time.monotonic() < deadline:
        pass
    assert verdicts(connector) == []  # complete, but the job began no rollout

    plain = make_connector(cell_config(sim_cell), camera_factory=simulated_camera_factory(source=sim_cell))
    plain_cell = a_job_cell(plain)
    plain_cell.rollout_begin(index=1, total=1)
    plain_cell.rollout_end()
    assert verdicts(plain) == []


class Published:
    """The agent's NATS link as the telemetry thread sees it: what it was given to publish, in order."""

    def __init__(self) -> None:
        self.messages: list[tuple[str, bytes]] = []

    def notify(self, subject: str, payload: bytes) -> None:
        self.messages.append((subject, payload))


def test_the_monitor_s_verdict_now_reaches_the_cell_page_while_the_job_runs(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig], connector: Connector, bus: Any,
) -> None:
    """The agent's telemetry (in process, and through a pod sidecar's observer op) carries the monitor's verdict
    to the FMS's telemetry store, which the cell page polls; a cell without a monitor publishes none."""
    from armnet_connector.observer import ObserverSession
    from armnet_fms.telemetry import TelemetryStore
    from armnet_node.metrics import AgentMetrics
    from armnet_node.sidecar_observer import parse_monitor
    from armnet_node.telemetry import CellTelemetry, TelemetrySettings
    from armnet_node.telemetry_sources import InProcessView, JobSource

    def published_by(view: Any) -> list[tuple[str, bytes]]:
        link = Published()
        CellTelemetry("cell-1", lambda: JobSource(view, (), None), link, AgentMetrics(),
                      TelemetrySettings()).publish_servos(JobSource(view, (), None))
        return link.messages

    cell = a_job_cell(connector)
    [(_, before)] = [m for m in published_by(InProcessView(connector.cell)) if m[0] == "telemetry.cell-1.monitor"]
    assert json.loads(before)["complete"] is False
    drive_to(bus, dict(TARGET_POSE))
    deadline = time.monotonic() + 30
    while not cell.is_complete(block=True) and time.monotonic() < deadline:
        pass

    [(subject, payload)] = [m for m in published_by(InProcessView(connector.cell)) if m[0].endswith(".monitor")]
    page = TelemetryStore(known_cells=lambda: {"cell-1"})
    assert page.accept(subject, payload, now=100.0)
    seen = page.view("cell-1", now=100.5)["monitor"]
    assert seen is not None and seen["complete"] is True and 0.0 < seen["score"] <= 1.0
    assert page.view("cell-1", now=110.0)["monitor"] is None  # stale: the job ended, the line goes
    through_sidecar = parse_monitor(ObserverSession(connector.cell).handle({"op": "monitor"})["monitor"])
    assert through_sidecar is not None and through_sidecar.complete is True

    plain = make_connector(cell_config(sim_cell), camera_factory=simulated_camera_factory(source=sim_cell))
    assert [s for s, _ in published_by(InProcessView(plain.cell)) if s.endswith(".monitor")] == []
    assert ObserverSession(plain.cell).handle({"op": "monitor"}) == {"ok": True, "monitor": None}
