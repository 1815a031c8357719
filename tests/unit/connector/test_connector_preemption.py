"""A preempted job stops at its next episode boundary: the grace window opens at the end of the open rollout.

The connector's side of a preemption (docs/connector.md, "Preemption"): the
agent asks ``stop_at_episode_end`` (in its process) or sends ``preempt`` on
``agent.sock`` (a pod's sidecar); the job's own ``rollout_end`` is the boundary.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_connector import Connector, ConnectorConfig
from armnet_connector.agent_inputs import AGENT_SOCKET, MAX_CANCEL_WHY
from armnet_connector.hardware import simulated_camera_factory
from armnet_runtime.context import Cell
from armnet_runtime.endpoints import OPERATOR_SOCKET, ROBOT_SOCKET
from armnet_sim import SimulatedCellProcess

from tests.support.sim_connector import request

pytestmark = pytest.mark.unit

WHY = "preempted: cell c1 is borrowed by CellQuota 'b'; its owner 'a' has job ns/x waiting"


@pytest.fixture
def agent_dir() -> Iterator[Path]:
    path = Path(tempfile.mkdtemp(prefix="anp-", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def connector(make_connector: Callable[..., Connector], cell_config: Callable[..., ConnectorConfig],
              agent_dir: Path) -> Connector:
    """A connector without arms to drive (rollouts need none), serving ``agent.sock`` as a pod's sidecar does."""
    return make_connector(cell_config(None, gracePeriodSeconds=30), observer_dir=agent_dir)


def a_job_cell(connector: Connector) -> Cell:
    """The customer SDK's cell handle: ``rollout_begin``/``rollout_end``/``is_shutting_down`` on the operator socket."""
    return Cell(robot_port=connector.robot_endpoint, operator_call_endpoint=connector.operator_endpoint)


def refusal(connector: Connector) -> dict[str, Any]:
    """What a motion request gets now."""
    return request(connector.socket_dir / ROBOT_SOCKET, {"op": "return_to_rest"})


def test_between_rollouts_the_grace_window_opens_at_the_next_rollouts_end(connector: Connector) -> None:
    """Not at once: the job may have asked is_shutting_down() already and be about to begin the next
    rollout, whose first move would then be refused."""
    job = a_job_cell(connector)
    job.rollout_begin(index=0, total=2)
    job.rollout_end()

    assert connector.cell.stop_at_episode_end(WHY) is False
    assert job.is_shutting_down() is False
    job.rollout_begin(index=1, total=2)
    assert refusal(connector).get("error_type") != "ShuttingDown"  # the episode moves
    job.rollout_end()

    assert job.is_shutting_down() is True
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == WHY
    reply = refusal(connector)
    assert reply["error_type"] == "ShuttingDown" and WHY in reply["error"]


def test_a_job_that_never_began_a_rollout_is_between_rollouts(connector: Connector) -> None:
    assert connector.cell.stop_at_episode_end(WHY) is True
    assert a_job_cell(connector).is_shutting_down() is True


def test_during_a_rollout_the_grace_window_opens_at_that_rollouts_end(connector: Connector) -> None:
    job = a_job_cell(connector)
    job.rollout_begin(index=0, total=2)

    assert connector.cell.stop_at_episode_end(WHY) is False

    assert job.is_shutting_down() is False  # the episode runs on, motion allowed
    assert not connector.interlock.tripped
    job.rollout_end()
    assert job.is_shutting_down() is True
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == WHY
    assert WHY in refusal(connector)["error"]


def test_a_second_request_changes_nothing_and_the_first_reason_stands(connector: Connector) -> None:
    job = a_job_cell(connector)
    job.rollout_begin(index=0, total=1)
    assert connector.cell.stop_at_episode_end(WHY) is False
    assert connector.cell.stop_at_episode_end("preempted: another reason") is False
    job.rollout_end()
    assert connector.cell.stop_at_episode_end("preempted: another reason") is True  # open already
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == WHY


def test_a_grace_window_already_open_is_left_as_it_is(connector: Connector) -> None:
    connector.cancel()  # a cancel came first: its window, its reason
    assert connector.cell.stop_at_episode_end(WHY) is True
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == "the job was cancelled"


def test_a_rollout_begun_after_the_request_to_a_job_that_ran_none_finds_the_job_shutting_down(
    connector: Connector,
) -> None:
    job = a_job_cell(connector)
    assert connector.cell.stop_at_episode_end(WHY) is True
    job.rollout_begin(index=0, total=1)  # a job that starts episodes only now gets none
    assert job.is_shutting_down() is True
    assert refusal(connector)["error_type"] == "ShuttingDown"


# -- the monitor's verdicts are no boundary ------------------------------------------------


@pytest.fixture
def monitored(sim_cell: SimulatedCellProcess, make_connector: Callable[..., Connector],
              cell_config: Callable[..., ConnectorConfig]) -> Connector:
    """A cell with a completion monitor on its simulated camera: it records a verdict on the open rollout."""
    completion = {"camera": "front", "region": {"left": 0.0, "top": 0.0, "width": 0.1, "height": 0.1},
                  "colour": {"hueMin": 100, "hueMax": 130, "saturationMin": 120, "valueMin": 80},
                  "consecutiveFrames": 1, "rateHz": 15}
    config = cell_config(sim_cell, completion=completion, gracePeriodSeconds=30)
    return make_connector(config, camera_factory=simulated_camera_factory(source=sim_cell))


def test_a_verdict_on_the_open_rollout_is_not_its_end(monitored: Connector) -> None:
    job = a_job_cell(monitored)
    job.rollout_begin(index=0, total=1)
    job.is_complete(block=True)  # the monitor has scored a frame: it can judge
    monitored.cell.record_monitor_verdict(told_complete=True)  # what telling the job "complete" records
    assert [e.kind for e in monitored.cell.rollouts] == ["begin", "verdict"]

    assert monitored.cell.stop_at_episode_end(WHY) is False

    assert job.is_shutting_down() is False
    job.rollout_end()
    assert job.is_shutting_down() is True


# -- agent.sock --------------------------------------------------------------------------


def test_the_preempt_op_before_any_rollout_opens_the_window_now(connector: Connector, agent_dir: Path) -> None:
    reply = request(agent_dir / AGENT_SOCKET, {"op": "preempt", "why": WHY})
    assert reply == {"ok": True, "applied": True, "now": True}
    assert a_job_cell(connector).is_shutting_down() is True


def test_the_preempt_op_during_a_rollout_waits_for_its_end_and_tells_when_asked_again(
    connector: Connector, agent_dir: Path,
) -> None:
    job = a_job_cell(connector)
    job.rollout_begin(index=3, total=5)
    assert request(agent_dir / AGENT_SOCKET, {"op": "preempt", "why": WHY})["now"] is False
    assert request(agent_dir / AGENT_SOCKET, {"op": "preempt", "why": WHY})["now"] is False
    job.rollout_end()
    assert request(agent_dir / AGENT_SOCKET, {"op": "preempt", "why": WHY})["now"] is True
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == WHY


@pytest.mark.parametrize("fields", [{}, {"why": None}, {"why": ""}, {"why": 7}, {"why": "x" * (MAX_CANCEL_WHY + 1)}])
def test_a_preempt_op_without_a_reason_of_1_to_500_characters_is_refused(
    connector: Connector, agent_dir: Path, fields: dict[str, Any],
) -> None:
    reply = request(agent_dir / AGENT_SOCKET, {"op": "preempt", **fields})
    assert reply["ok"] is False and reply["error_type"] == "ProtocolError"
    assert "'why'" in reply["error"]
    assert not connector.cell.deadline.deadline_passed


def test_the_jobs_own_sockets_serve_no_preempt_op(connector: Connector) -> None:
    for name in (ROBOT_SOCKET, OPERATOR_SOCKET):
        reply = request(connector.socket_dir / name, {"op": "preempt", "why": WHY})
        assert reply["ok"] is False and reply["error_type"] == "UnknownOp"
    assert not connector.cell.deadline.deadline_passed
