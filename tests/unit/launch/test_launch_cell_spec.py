"""The local cell's shape and the env a job on it receives (pure, no processes)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
from armnet_launch.cell_spec import (
    LocalCellError,
    LocalCellFile,
    build_job_env,
    load_cell_file,
    plan_layout,
    resolve_spec,
)
from armnet_runtime import env as env_keys
from armnet_runtime.cell_config import parse_cell_config

pytestmark = pytest.mark.unit

RUN_DIR = Path("/tmp/armnet-run-x")


def spec_for(**overrides: object):  # type: ignore[no-untyped-def]
    base: dict[str, object] = {"embodiment": None, "preset": None, "task": None, "grace_seconds": None}
    base.update(overrides)
    return resolve_spec(**base)  # type: ignore[arg-type]


def env_for(spec, **kw: object) -> dict[str, str]:  # type: ignore[no-untyped-def]
    return build_job_env(spec, plan_layout(spec, RUN_DIR), job_id="j1", timeout_seconds=30, args={"a": 1})


def test_the_default_cell_is_one_so101_arm_with_a_front_camera_and_a_safety_limit() -> None:
    spec = spec_for()
    assert (spec.preset, spec.embodiment, spec.arm_names) == ("so101", "lerobot/so-101", ("arm",))
    cell = parse_cell_config(env_for(spec)[env_keys.CELL_CONFIG])
    front = cell.camera_configs["front"]
    assert (front.width, front.height, front.fps) == (640, 480, 30)
    assert cell.cell_safety_limit("lerobot/so-101") == spec.safety_limit
    assert cell.robot_id == "so101-sim"
    assert cell.calibration_file_path == "/tmp/armnet-run-x/calibration/so101-sim.json"


def test_the_env_holds_exactly_the_cell_keys() -> None:
    env = env_for(spec_for(task="pick"))
    assert env[env_keys.JOB_ID] == "j1"
    assert env[env_keys.TASK] == "pick"
    assert env[env_keys.TIMEOUT_SECONDS] == "30"
    assert json.loads(env[env_keys.ARGS]) == {"a": 1}
    assert env[env_keys.CELL_SOCKET] == "unix:///tmp/armnet-run-x/sockets/robot.sock"
    assert env[env_keys.OPERATOR_CALL_ENDPOINT] == "unix:///tmp/armnet-run-x/sockets/operator.sock"
    assert env[env_keys.CALIBRATION_DIR] == "/tmp/armnet-run-x/calibration"
    assert env[env_keys.OUTPUT_DIR] == "/tmp/armnet-run-x/output"
    assert env[env_keys.HF_LEROBOT_HOME] == "/tmp/armnet-run-x/output/lerobot"  # LeRobot's datasets are kept
    assert all(key.startswith(("ARMNET_", "REMOTEROBOT_", "HF_")) for key in env)
    assert "PATH" not in env


def test_lerobots_tools_in_the_job_reach_the_cell_and_calibrate_only_where_the_cell_allows_it() -> None:
    spec = spec_for()
    assert env_for(spec)[env_keys.LEROBOT_TOOLS] == "remote"
    assert env_for(spec)[env_keys.CALIBRATION_JOBS] == "0"
    assert env_for(dataclasses.replace(spec, allow_calibration_jobs=True))[env_keys.CALIBRATION_JOBS] == "1"


def test_the_bimanual_preset_selects_each_arm_on_the_one_robot_socket() -> None:
    spec = spec_for(embodiment="lerobot/bimanual_so101")
    cell = parse_cell_config(env_for(spec)[env_keys.CELL_CONFIG])
    assert spec.preset == "bimanual_so101"
    assert cell.arms["left"].robot_port == "unix:///tmp/armnet-run-x/sockets/robot.sock?arm=left"
    assert cell.arms["right"].robot_id == "so101-sim_right"
    assert cell.arms["right"].calibration_file_path == "/tmp/armnet-run-x/calibration/so101-sim_right.json"


def test_an_embodiment_that_contradicts_the_preset_is_refused_with_the_fix() -> None:
    with pytest.raises(LocalCellError, match="--embodiment lerobot/bimanual_so101"):
        spec_for(embodiment="lerobot/so-101", preset="bimanual_so101")


def test_an_unknown_embodiment_names_the_supported_ones() -> None:
    with pytest.raises(LocalCellError, match="lerobot/so-101"):
        spec_for(embodiment="acme/arm")


def test_flags_win_over_the_cell_file_which_wins_over_defaults() -> None:
    file = LocalCellFile(task="stack", grace_period_seconds=2, safety_limit=4.0, reset_timeout_seconds=1)
    spec = spec_for(task="pick", cell_file=file)
    assert (spec.task, spec.grace_seconds, spec.safety_limit, spec.reset_timeout_seconds) == ("pick", 2, 4.0, 1)
    assert spec_for(grace_seconds=0.5, cell_file=file).grace_seconds == 0.5


def test_a_cell_file_with_a_typo_is_refused_naming_the_field(tmp_path: Path) -> None:
    path = tmp_path / "cell.json"
    path.write_text(json.dumps({"safty_limit": 3}))
    with pytest.raises(LocalCellError, match="safty_limit"):
        load_cell_file(path)


def test_a_yaml_cell_file_can_pick_the_bimanual_preset_and_cameras(tmp_path: Path) -> None:
    path = tmp_path / "cell.yaml"
    path.write_text("preset: bimanual_so101\ncameras:\n  wrist: {width: 320, height: 240, fps: 15}\n")
    spec = spec_for(cell_file=load_cell_file(path))
    assert spec.is_bimanual
    assert [(c.name, c.width, c.fps) for c in spec.cameras] == [("wrist", 320, 15)]


def test_the_cells_safety_policy_and_calibration_setting_reach_the_connector() -> None:
    from armnet_launch.sim_cell import build_connector_config

    spec = spec_for()
    layout = plan_layout(spec, RUN_DIR)
    ports = {arm.name: "/dev/null" for arm in layout.arms}
    default = build_connector_config(spec, layout, ports)
    assert (default.safety_policy, default.allow_calibration_jobs) == ("clamp", False)
    file = LocalCellFile(safety_policy="trip", allow_calibration_jobs=True)
    chosen = build_connector_config(spec_for(cell_file=file), layout, ports)
    assert (chosen.safety_policy, chosen.allow_calibration_jobs) == ("trip", True)


def test_a_nan_safety_limit_in_the_cell_file_is_refused() -> None:
    with pytest.raises(ValueError, match="safety_limit"):
        LocalCellFile(safety_limit=float("nan"))


def test_a_cell_file_sets_the_completion_monitor_of_a_local_run(tmp_path: Path) -> None:
    from armnet_launch.sim_cell import build_connector_config

    path = tmp_path / "cell.yaml"
    path.write_text(
        "completion:\n  camera: front\n  region: {left: 0.7, top: 0.1, width: 0.1, height: 0.1}\n"
        "  colour: {hueMin: 170, hueMax: 8}\n  consecutiveFrames: 2\n"
    )
    spec = spec_for(cell_file=load_cell_file(path))
    layout = plan_layout(spec, RUN_DIR)
    config = build_connector_config(spec, layout, {arm.name: "/dev/null" for arm in layout.arms})
    assert config.completion is not None and config.completion.consecutive_frames == 2


@pytest.mark.parametrize(("completion", "says"), [
    ("  camera: wrist\n  region: {left: 0.7, top: 0.1, width: 0.1, height: 0.1}\n  colour: {hueMin: 170, hueMax: 8}\n",
     "completion.camera 'wrist' is not a camera of this cell"),
    ("  camera: front\n  scorer: classifier\n  classifier: {modelFrom: {configMapKeyRef: {name: reach, key: reach.onnx}}}\n",
     "a local run's cell file gives completion.classifier.model"),
], ids=["a camera the cell lacks", "a classifier model from a ConfigMap"])
def test_a_cell_file_whose_completion_a_local_run_cannot_serve_is_refused(
        tmp_path: Path, completion: str, says: str) -> None:
    path = tmp_path / "cell.yaml"
    path.write_text("completion:\n" + completion)
    with pytest.raises(LocalCellError, match=says):
        spec_for(cell_file=load_cell_file(path))
