"""The launch plan of a job on a cell, and the rule for when a job may launch."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from armnet_launch.plan import LABEL_CELL, LABEL_JOB_UID
from armnet_launch.sim_cell import build_connector_config
from armnet_node.model import parse_cell, parse_job, should_launch
from armnet_node.plan import HostPaths, LaunchError, completion_files_refused, plan_launch
from armnet_runtime import env as env_keys
from armnet_runtime.cell_config import parse_cell_config

pytestmark = pytest.mark.unit

PATHS = HostPaths(Path("/var/lib/armnet-agent"))


def cell_obj(**spec: Any) -> dict[str, Any]:
    base: dict[str, Any] = {
        "embodiment": "lerobot/so-101", "nodeName": "host-1", "simulated": True, "task": "pick",
        "robot": {"robotId": "follower-1", "safetyLimit": 7.5},
        "cameras": {"front": {"indexOrPath": 0, "width": 320, "height": 240, "fps": 15}},
        "gracePeriodSeconds": 4, "resetTimeoutSeconds": 90,
    }
    base.update(spec)
    return {"metadata": {"name": "cell-1", "resourceVersion": "7"}, "spec": base,
            "status": {"currentJob": "team-a/job-1"}}


def job_obj(**spec: Any) -> dict[str, Any]:
    base: dict[str, Any] = {"image": "localhost/pick:1", "embodiment": "lerobot/so-101", "timeoutSeconds": 60,
                            "args": {"episodes": 3}}
    base.update(spec)
    return {"metadata": {"name": "job-1", "namespace": "team-a", "uid": "uid-1", "resourceVersion": "9"},
            "spec": base, "status": {"phase": "dispatched", "cellName": "cell-1"}}


def test_a_dispatched_job_bound_both_ways_launches() -> None:
    assert should_launch(parse_job(job_obj()), parse_cell(cell_obj()))


def test_a_job_the_cell_does_not_name_never_launches() -> None:
    cell = cell_obj()
    cell["status"]["currentJob"] = "team-a/other"
    assert not should_launch(parse_job(job_obj()), parse_cell(cell))


def test_a_cancelled_job_never_launches() -> None:
    assert not should_launch(parse_job(job_obj(cancel=True)), parse_cell(cell_obj()))


def test_the_job_env_holds_exactly_the_sdk_variables_and_a_cell_config_the_sdk_parses() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {})
    env = plan.container.env
    assert env[env_keys.JOB_ID] == "uid-1"
    assert json.loads(env[env_keys.ARGS]) == {"episodes": 3}
    assert env[env_keys.TIMEOUT_SECONDS] == "60"
    config = parse_cell_config(env[env_keys.CELL_CONFIG])
    assert config.cell_name == "cell-1"
    assert config.safety_limit == 7.5
    assert config.robot_id == "follower-1"
    assert set(config.camera_configs) == {"front"}
    assert env[env_keys.VOLUME_HOME].endswith("/volumes/team-a")


def test_the_cells_cameras_reach_the_launch_plan_as_the_cell_describes_them() -> None:
    cell = parse_cell(cell_obj())
    plan = plan_launch(parse_job(job_obj()), cell, PATHS, {})
    assert plan.cell_spec.cameras == cell.cameras
    [front] = plan.cell_spec.cameras
    assert (front.name, front.index_or_path, front.width, front.height, front.fps) == ("front", 0, 320, 240, 15)


def test_the_cell_spec_sets_grace_and_reset_timeout_of_the_connector() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {})
    assert plan.grace_seconds == 4
    assert plan.cell_spec.reset_timeout_seconds == 90


def test_the_cells_safety_settings_reach_its_connector_unchanged() -> None:
    cell = parse_cell(cell_obj(safetyPolicy="trip", allowCalibrationJobs=True, registerBounds={"Acceleration": [0, 100]}))
    plan = plan_launch(parse_job(job_obj()), cell, PATHS, {})
    config = build_connector_config(plan.cell_spec, plan.layout, {"arm": "/dev/pts/9"})
    assert config.safety_policy == "trip"
    assert config.allow_calibration_jobs is True
    assert config.register_bounds == {"Acceleration": (0, 100)}


def test_a_cell_that_says_nothing_gets_the_safe_defaults() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {})
    config = build_connector_config(plan.cell_spec, plan.layout, {"arm": "/dev/pts/9"})
    assert config.safety_policy == "clamp"
    assert config.allow_calibration_jobs is False


def test_secrets_become_env_vars_listed_in_armnet_secrets_and_never_labels() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {"HF_TOKEN": "hf_abc"})
    assert plan.container.env["HF_TOKEN"] == "hf_abc"
    assert json.loads(plan.container.env[env_keys.SECRETS]) == ["HF_TOKEN"]
    assert "hf_abc" not in json.dumps(dict(plan.container.labels))


def test_the_container_is_labelled_with_its_cell_and_job_and_named_after_the_job() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {})
    assert plan.container.labels[LABEL_CELL] == "cell-1"
    assert plan.container.labels[LABEL_JOB_UID] == "uid-1"
    assert plan.container.name == "armnet-uid-1"


def test_calibration_is_mounted_read_only_and_the_sockets_read_write() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {})
    modes = {m.inside: m.read_only for m in plan.container.mounts}
    assert modes[str(plan.layout.calibration_dir)] is True
    assert modes[str(plan.layout.socket_dir)] is False


def test_each_job_gets_its_own_writable_output_directory_outside_its_run_directory() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {})
    output = plan.layout.output_dir
    assert output == PATHS.output_dir("uid-1")
    assert not output.is_relative_to(PATHS.run_dir("uid-1"))  # the run directory is removed when the job ends
    assert plan.container.env[env_keys.OUTPUT_DIR] == str(output)
    assert plan.container.env[env_keys.HF_LEROBOT_HOME] == str(output / "lerobot")
    assert {m.inside: m.read_only for m in plan.container.mounts}[str(output)] is False


def test_args_over_the_kernels_env_limit_fail_the_launch_with_a_clear_message() -> None:
    with pytest.raises(LaunchError, match="ARMNET_ARGS.*128 KiB"):
        plan_launch(parse_job(job_obj(args={"blob": "x" * 140_000})), parse_cell(cell_obj()), PATHS, {})


def test_args_just_under_the_limit_are_passed_whole() -> None:
    plan = plan_launch(parse_job(job_obj(args={"blob": "x" * 120_000})), parse_cell(cell_obj()), PATHS, {})
    assert len(json.loads(plan.container.env[env_keys.ARGS])["blob"]) == 120_000


def test_a_bimanual_cell_gets_per_arm_endpoints_and_calibration_files() -> None:
    cell = cell_obj(embodiment="lerobot/bimanual_so101", robot=None, arms={
        "left": {"robotId": "pair_left"}, "right": {"robotId": "pair_right"}})
    job = job_obj(embodiment="lerobot/bimanual_so101")
    plan = plan_launch(parse_job(job), parse_cell(cell), PATHS, {})
    config = json.loads(plan.container.env[env_keys.CELL_CONFIG])
    assert set(config["arms"]) == {"left", "right"}
    assert config["arms"]["left"]["robot_id"] == "pair_left"


def test_a_hardware_cell_is_refused_with_what_to_do() -> None:
    with pytest.raises(LaunchError, match="simulated"):
        plan_launch(parse_job(job_obj()), parse_cell(cell_obj(simulated=False)), PATHS, {})


COMPLETION = {"camera": "front", "region": {"left": 0.7, "top": 0.1, "width": 0.1, "height": 0.1},
              "colour": {"hueMin": 170, "hueMax": 8}, "consecutiveFrames": 4, "rateHz": 8}


def test_the_cells_completion_monitor_reaches_its_connector() -> None:
    plan = plan_launch(parse_job(job_obj()), parse_cell(cell_obj(completion=COMPLETION)), PATHS, {})
    config = build_connector_config(plan.cell_spec, plan.layout, {"arm": "/dev/pts/9"})
    assert config.completion is not None
    assert (config.completion.camera, config.completion.consecutive_frames, config.completion.rate_hz) == ("front", 4, 8)
    assert build_connector_config(
        plan_launch(parse_job(job_obj()), parse_cell(cell_obj()), PATHS, {}).cell_spec, plan.layout, {"arm": "/x"}
    ).completion is None


@pytest.mark.parametrize(("completion", "says"), [
    ({**COMPLETION, "camera": "wrist"}, "completion.camera 'wrist' is not a camera of this cell; name one of ['front']"),
    ({**COMPLETION, "region": {"left": 0.5, "top": 0.5, "width": 0, "height": 0.1}}, "completion.region is empty"),
    ({**COMPLETION, "rateHz": 1e6}, "give 0.5 to 30 frames per second"),
])
def test_a_cell_with_a_bad_completion_is_an_error_naming_the_cell_and_the_fix(
    completion: dict[str, Any], says: str,
) -> None:
    with pytest.raises(ValueError, match="^Cell cell-1: invalid spec") as raised:
        parse_cell(cell_obj(completion=completion))
    assert says in str(raised.value)


CLASSIFIER = {"camera": "front", "scorer": "classifier"}


@pytest.mark.parametrize("files", [
    {"classifier": {"model": "/etc/armnet/reach.onnx"}},
    {"classifier": {"model": "/var/lib/armnet/models-old/reach.onnx"}},  # a sibling sharing the prefix
    {"scorer": "service", "service": {"url": "http://judge:8080/s",
                                      "tokenFile": "/var/run/secrets/kubernetes.io/serviceaccount/token"}},
])
def test_a_cell_naming_a_completion_file_outside_the_agents_directories_is_not_launched(files: dict[str, Any]) -> None:
    cell = parse_cell(cell_obj(completion={**CLASSIFIER, **files}))
    refused = completion_files_refused(cell, PATHS)
    assert refused is not None and refused.startswith("cell cell-1: ")
    assert "is outside the directories this node agent reads completion files from" in refused
    assert "/var/lib/armnet/models, /var/lib/armnet/secrets" in refused


def test_a_cell_naming_a_completion_file_inside_them_is_launched_with_it() -> None:
    cell = parse_cell(cell_obj(completion={**CLASSIFIER, "classifier": {"model": "/var/lib/armnet/models/reach.onnx"}}))
    assert completion_files_refused(cell, PATHS) is None
    plan = plan_launch(parse_job(job_obj()), cell, PATHS, {})
    config = build_connector_config(plan.cell_spec, plan.layout, {"arm": "/dev/pts/9"})
    assert config.completion is not None and config.completion.classifier is not None
    assert config.completion.classifier.model == "/var/lib/armnet/models/reach.onnx"


def test_the_completion_directories_come_from_the_flags_else_the_env_where_empty_means_none() -> None:
    from armnet_node.cli import completion_dirs

    assert completion_dirs(["/srv/models"], "/a:/b") == ("/srv/models",)
    assert completion_dirs(None, "/a:/b") == ("/a", "/b")
    assert completion_dirs(None, "") == ()
    assert completion_dirs(None, None) == ("/var/lib/armnet/models", "/var/lib/armnet/secrets")
