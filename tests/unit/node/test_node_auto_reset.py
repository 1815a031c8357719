"""A cell's scripted reset as the node agent sees it: the Cell's spec, the connector it starts, the alert, the metric.

The connector side (the moves, the monitor's judgement, the fallback) is tested in
tests/unit/connector/test_connector_scripted_reset.py; here a real simulated cell with
its connector (``LocalCell``, as the container launcher runs it) makes the resets.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_launch.cell_spec import LocalCellFile, resolve_spec
from armnet_launch.sim_cell import LocalCell, build_connector_config
from armnet_node.health import auto_reset_condition
from armnet_node.launchers import ContainerSession
from armnet_node.metrics import AgentMetrics
from armnet_node.model import parse_cell, parse_job
from armnet_node.plan import plan_launch
from armnet_node.runner import count_auto_resets
from armnet_runtime.context import Cell
from armnet_sim.render import TARGET_POSE, target_region

from tests.unit.node.test_node_plan import COMPLETION, PATHS, cell_obj, job_obj

pytestmark = pytest.mark.unit

SCRIPTED = {"mode": "Scripted", "poses": [{"shoulder_lift": -25, "elbow_flex": 10}], "attempts": 2,
            "settleSeconds": 0.2}


def test_the_cells_scripted_reset_reaches_its_connector() -> None:
    cell = parse_cell(cell_obj(completion=COMPLETION, reset=SCRIPTED))
    assert cell.reset is not None and cell.reset.scripted
    plan = plan_launch(parse_job(job_obj()), cell, PATHS, {})
    config = build_connector_config(plan.cell_spec, plan.layout, {"arm": "/dev/pts/9"})
    assert config.reset == cell.reset
    assert parse_cell(cell_obj()).reset is None


@pytest.mark.parametrize(("spec", "says"), [
    ({"reset": SCRIPTED}, "reset.mode Scripted needs the cell's completion monitor (spec.completion)"),
    ({"reset": {**SCRIPTED, "poses": [{"left_elbow_flex": 10}]}, "completion": COMPLETION},
     "reset.poses[0]: 'left_elbow_flex' is not a joint of this cell"),
    ({"reset": {**SCRIPTED, "attempts": 0}, "completion": COMPLETION}, "reset.attempts is 0; give 1 to 10"),
])
def test_a_cell_whose_scripted_reset_cannot_work_is_an_error_naming_the_cell_and_the_fix(
    spec: dict[str, Any], says: str,
) -> None:
    with pytest.raises(ValueError, match="^Cell cell-1: invalid spec") as raised:
        parse_cell(cell_obj(**spec))
    assert says in str(raised.value)


def test_a_bimanual_cell_names_each_arm_s_joints() -> None:
    cell = parse_cell(cell_obj(
        embodiment="lerobot/bimanual_so101", robot=None, arms={"left": {"robotId": "p_left"}, "right": {}},
        completion=COMPLETION, reset={**SCRIPTED, "poses": [{"left_elbow_flex": 10, "right_elbow_flex": -10}]}))
    assert cell.reset is not None and cell.reset.poses == ({"left_elbow_flex": 10, "right_elbow_flex": -10},)


def test_auto_reset_working_says_false_only_when_a_scripted_reset_fell_back_to_the_person() -> None:
    assert auto_reset_condition(None).status == "True"
    worked = auto_reset_condition({"outcome": "worked", "message": "scripted reset worked on try 1: ..."})
    assert (worked.status, worked.reason) == ("True", "Worked")
    fell = auto_reset_condition({"outcome": "fell_back", "message": "scripted reset failed 3 time(s), ..."})
    assert (fell.type, fell.status, fell.reason, fell.message) == (
        "AutoResetWorking", "False", "FellBackToOperator", "scripted reset failed 3 time(s), ...")


def monitored_cell_file(poses: list[dict[str, float]]) -> LocalCellFile:
    left, top, width, height = target_region(640, 480)
    return LocalCellFile.model_validate({
        "completion": {"camera": "front", "region": {"left": left, "top": top, "width": width, "height": height},
                       "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80},
                       "consecutiveFrames": 3, "rateHz": 15},
        "reset": {"mode": "Scripted", "poses": poses, "attempts": 2, "settleSeconds": 0.2},
        "reset_timeout_seconds": 30,
    })


@pytest.fixture
def run_dir() -> Iterator[Path]:
    # Unix socket paths are limited to 108 bytes: pytest's tmp_path is often longer.
    path = Path(tempfile.mkdtemp(prefix="anr-", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


def test_a_job_s_scripted_resets_reach_the_alert_and_the_metric_through_the_session_and_its_record(
    run_dir: Path,
) -> None:
    spec = resolve_spec(embodiment=None, preset="so101", task=None, grace_seconds=None,
                        cell_file=monitored_cell_file([dict(TARGET_POSE)]))
    with LocalCell(spec, run_dir, auto_confirm_reset=True) as local:
        assert local.connector is not None
        session = ContainerSession(None, None, local)  # type: ignore[arg-type]
        assert session.auto_reset_latest() is None
        Cell(robot_port=local.connector.robot_endpoint,
             operator_call_endpoint=local.connector.operator_endpoint).reset()  # the poses end on the target

        live = session.auto_reset_latest()
        assert live is not None and live["outcome"] == "fell_back"
        assert auto_reset_condition(live).status == "False"
        record = session.record()

    metrics = AgentMetrics()
    count_auto_resets(metrics, record)
    sample = metrics.registry.get_sample_value
    assert sample("armnet_agent_auto_resets_total", {"outcome": "fell_back"}) == 1
    assert sample("armnet_agent_auto_resets_total", {"outcome": "try_failed"}) == 2
    assert sample("armnet_agent_auto_resets_total", {"outcome": "worked"}) is None
