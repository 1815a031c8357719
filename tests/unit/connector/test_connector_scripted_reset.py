"""``ctx.cell.reset()`` on a cell with a scripted reset: the real connector, the simulated SO-101, the real monitor.

The simulator's camera draws a red disc on the arm's end effector and a blue pad
where the disc lands at ``TARGET_POSE``; the cell's completion monitor (the region
scorer on rendered frames) judges whether the scene is back at its start. The job
is the SDK's ``Cell``; nobody confirms anything unless a test says so.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import pytest
from armnet_connector import Connector, ConnectorConfig, LocalOperatorInputs
from armnet_connector.hardware import simulated_camera_factory
from armnet_connector.interlock import TripReason
from armnet_runtime.context import Cell
from armnet_sim import SimulatedCellProcess
from armnet_sim.render import TARGET_POSE

from tests.unit.connector.test_connector_completion import completion_of_the_target, drive_to

pytestmark = pytest.mark.unit

AWAY = {"shoulder_lift": -25.0, "elbow_flex": 10.0, "wrist_flex": 15.0}


class Person:
    """The person at the cell: counts the resets that asked for them, and confirms each if told to."""

    def __init__(self, *, confirms: bool) -> None:
        self.asked = 0
        self.confirms = confirms

    def __call__(self, inputs: LocalOperatorInputs) -> None:
        self.asked += 1
        if self.confirms:
            inputs.confirm_reset()


def scripted_cell(sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
                  cell_config: Callable[..., ConnectorConfig], person: Person, poses: list[dict[str, float]],
                  **overrides: Any) -> Connector:
    config = cell_config(sim_cell, completion=completion_of_the_target(),
                         reset={"mode": "Scripted", "poses": poses, "attempts": 2, "settleSeconds": 0.2},
                         **overrides)
    return make_connector(config, camera_factory=simulated_camera_factory(source=sim_cell),
                          inputs=LocalOperatorInputs(on_reset_requested=person))


def a_job_cell(connector: Connector) -> Cell:
    return Cell(robot_port=connector.robot_endpoint, operator_call_endpoint=connector.operator_endpoint)


def until_complete(cell: Cell) -> bool:
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if cell.is_complete(block=True).complete:
            return True
    return False


def test_a_reset_whose_poses_leave_the_target_ends_without_anyone(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig], motors: dict[str, Any], calibration: dict[str, Any],
) -> None:
    from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

    person = Person(confirms=False)
    connector = scripted_cell(sim_cell, make_connector, cell_config, person, [AWAY])
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    bus.connect()
    bus.enable_torque()
    cell = a_job_cell(connector)
    drive_to(bus, dict(TARGET_POSE))
    assert until_complete(cell)

    cell.reset()  # resetTimeoutSeconds is 2: a reset that waited for a person would raise

    assert person.asked == 0
    present = bus.sync_read("Present_Position")
    assert all(abs(present[joint] - angle) < 3.0 for joint, angle in AWAY.items()), present
    assert cell.is_complete(block=True).complete is False
    assert connector.counters.auto_resets_worked == 1
    assert connector.counters.auto_reset_attempts_failed == connector.counters.auto_resets_fell_back == 0
    assert connector.safety_report().clamps_total == 0  # the connector's own steps stay inside the limit
    latest = connector.safety_report().as_status()["autoResets"]["latest"]
    assert (latest["outcome"], [a["reset"] for a in latest["attempts"]]) == ("worked", [True])
    bus.disconnect()


def test_a_reset_whose_poses_end_on_the_target_tries_again_then_asks_the_person(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig],
) -> None:
    person = Person(confirms=True)
    connector = scripted_cell(sim_cell, make_connector, cell_config, person, [AWAY, dict(TARGET_POSE)])
    cell = a_job_cell(connector)

    cell.reset()  # the person's confirmation ends it

    assert person.asked == 1
    counters = connector.record().counters
    assert (counters["auto_reset_attempts_failed"], counters["auto_resets_fell_back"],
            counters["auto_resets_worked"]) == (2, 1, 0)
    [report] = connector.cell.auto_resets
    assert report.outcome == "fell_back" and [a.reset for a in report.attempts] == [False, False]
    assert "the completion monitor still sees the task done" in report.attempts[-1].detail
    assert "the person at the cell is asked to reset it" in report.message
    status = connector.safety_report().as_status()["autoResets"]
    assert (status["fell_back"], status["failedAttempts"]) == (1, 2)


def test_a_reset_that_fell_back_and_nobody_confirmed_times_out_as_a_manual_one(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig],
) -> None:
    from armnet_runtime import ResetTimeoutException

    person = Person(confirms=False)
    connector = scripted_cell(sim_cell, make_connector, cell_config, person, [dict(TARGET_POSE)])
    with pytest.raises(ResetTimeoutException, match="no operator confirmed the reset within 2 s"):
        a_job_cell(connector).reset()
    assert person.asked == 1
    assert connector.record().trip_reason == TripReason.RESET_TIMEOUT


def test_a_scripted_reset_on_a_trip_policy_cell_with_a_small_step_limit_never_trips_it(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig],
) -> None:
    person = Person(confirms=False)
    config = cell_config(sim_cell, completion=completion_of_the_target(), safetyPolicy="trip",
                         reset={"mode": "Scripted", "poses": [AWAY], "attempts": 1, "settleSeconds": 0.2})
    config.arms["arm"].safety_limit = 3.0  # degrees per write; the walk's speed (4000 ticks/s) goes 7 per tick
    connector = make_connector(config, camera_factory=simulated_camera_factory(source=sim_cell),
                               inputs=LocalOperatorInputs(on_reset_requested=person))

    a_job_cell(connector).reset()

    assert (person.asked, connector.counters.auto_resets_worked) == (0, 1)
    report = connector.safety_report()
    assert (report.refusals_total, report.interlock_trips) == (0, 0)
    assert max(report.largest_requested_step.values()) <= 3.0 * 4095 / 360  # raw ticks


def test_the_interlock_tripped_during_a_scripted_reset_stops_the_arm_where_it_is(
    sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
    cell_config: Callable[..., ConnectorConfig], motors: dict[str, Any], calibration: dict[str, Any],
) -> None:
    from armnet_runtime.lerobot.remote_feetech import RemoteFeetechMotorsBus

    person = Person(confirms=True)
    far = {"shoulder_lift": -60.0, "elbow_flex": 60.0}
    connector = scripted_cell(sim_cell, make_connector, cell_config, person, [far], restSpeedTicksPerSecond=300)
    cell = a_job_cell(connector)
    tripper = threading.Timer(1.0, lambda: connector.cancel("the job was cancelled"))
    tripper.start()

    with pytest.raises(RuntimeError, match="grace window"):
        cell.reset()

    tripper.join()
    bus = RemoteFeetechMotorsBus(port=connector.robot_endpoint, motors=motors, calibration=calibration)
    bus.connect()
    first = bus.sync_read("Present_Position")
    time.sleep(1.0)
    later = bus.sync_read("Present_Position")
    assert all(abs(later[j] - first[j]) < 1.0 for j in far), (first, later)  # no motion in the grace window
    assert abs(later["shoulder_lift"] - far["shoulder_lift"]) > 10.0  # it stopped on its way
    assert person.asked == 0
    assert connector.counters.auto_resets_stopped == 1
    assert connector.counters.auto_reset_attempts_failed == 0
    [report] = connector.cell.auto_resets
    assert report.outcome == "stopped"
    bus.disconnect()
