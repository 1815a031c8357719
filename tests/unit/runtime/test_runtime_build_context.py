"""build_context: env vars, the ARMNET_CELL_CONFIG document, secrets, camera configs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from armnet_runtime import env
from armnet_runtime.cell_config import CellConfigError, build_camera_configs, parse_cell_config
from armnet_runtime.context import RuntimeArm, build_context

pytestmark = pytest.mark.unit

ROBOT = "unix:///run/armnet/robot.sock"
OPERATOR = "unix:///run/armnet/operator.sock"


@pytest.fixture
def job_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    """A clean environment with only the three required job variables set."""
    for key in list(vars(env).values()):
        if isinstance(key, str) and (key.startswith(("ARMNET_", "REMOTEROBOT_"))):
            monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv(env.JOB_ID, "job-1")
    monkeypatch.setenv(env.EMBODIMENT, "lerobot/so-101")
    monkeypatch.setenv(env.TASK, "pick")
    return monkeypatch


def set_config(monkeypatch: pytest.MonkeyPatch, document: dict[str, Any]) -> None:
    monkeypatch.setenv(env.CELL_CONFIG, json.dumps(document))


def test_env_keys_have_the_documented_values() -> None:
    assert {
        "JOB_ID": env.JOB_ID, "EMBODIMENT": env.EMBODIMENT, "TASK": env.TASK,
        "TIMEOUT_SECONDS": env.TIMEOUT_SECONDS, "ARGS": env.ARGS, "CELL_CONFIG": env.CELL_CONFIG,
        "CELL_SOCKET": env.CELL_SOCKET, "OPERATOR_CALL_ENDPOINT": env.OPERATOR_CALL_ENDPOINT,
        "LOCAL_CONTROL_ENDPOINT": env.LOCAL_CONTROL_ENDPOINT,
        "LOCAL_CONTAINER": env.LOCAL_CONTAINER, "ROBOT_ID": env.ROBOT_ID,
        "CALIBRATION_DIR": env.CALIBRATION_DIR, "CALIBRATION_FILE_PATH": env.CALIBRATION_FILE_PATH,
        "CACHE_HOME": env.CACHE_HOME, "VOLUME_HOME": env.VOLUME_HOME, "HF_HOME": env.HF_HOME,
        "SECRETS": env.SECRETS,
    } == {
        "JOB_ID": "ARMNET_JOB_ID", "EMBODIMENT": "ARMNET_EMBODIMENT", "TASK": "ARMNET_TASK",
        "TIMEOUT_SECONDS": "ARMNET_TIMEOUT_SECONDS", "ARGS": "ARMNET_ARGS",
        "CELL_CONFIG": "ARMNET_CELL_CONFIG", "CELL_SOCKET": "ARMNET_CELL_SOCKET",
        "OPERATOR_CALL_ENDPOINT": "ARMNET_OPERATOR_CALL_ENDPOINT",
        "LOCAL_CONTROL_ENDPOINT": "ARMNET_LOCAL_CONTROL_ENDPOINT",
        "LOCAL_CONTAINER": "ARMNET_LOCAL_CONTAINER", "ROBOT_ID": "ARMNET_ROBOT_ID",
        "CALIBRATION_DIR": "ARMNET_CALIBRATION_DIR",
        "CALIBRATION_FILE_PATH": "ARMNET_CALIBRATION_FILE_PATH",
        "CACHE_HOME": "REMOTEROBOT_CACHE_HOME", "VOLUME_HOME": "REMOTEROBOT_VOLUME_HOME",
        "HF_HOME": "HF_HOME", "SECRETS": "ARMNET_SECRETS",
    }


@pytest.mark.parametrize("missing", [env.JOB_ID, env.EMBODIMENT, env.TASK])
def test_a_missing_job_variable_names_all_three(job_env: pytest.MonkeyPatch, missing: str) -> None:
    job_env.delenv(missing)
    with pytest.raises(RuntimeError, match="ARMNET_JOB_ID, ARMNET_EMBODIMENT, ARMNET_TASK"):
        build_context()


def test_minimal_context(job_env: pytest.MonkeyPatch) -> None:
    ctx = build_context()
    assert (ctx.job_id, ctx.embodiment, ctx.task) == ("job-1", "lerobot/so-101", "pick")
    assert ctx.args == {} and ctx.secrets == {} and ctx.camera_configs == {}
    assert ctx.timeout_seconds is None and ctx.cache_home is None and ctx.volume.root is None
    assert ctx.cell.robot_port is None and ctx.cell.operator_call_endpoint is None
    assert ctx.cell.arms == {} and ctx.cell.is_local_container is False


def test_args_timeout_volume_and_cache_come_from_env(job_env: pytest.MonkeyPatch) -> None:
    job_env.setenv(env.ARGS, '{"seed": 3}')
    job_env.setenv(env.TIMEOUT_SECONDS, "90")
    job_env.setenv(env.VOLUME_HOME, "/vol")
    job_env.setenv(env.CACHE_HOME, "/cache")
    job_env.setenv(env.LOCAL_CONTAINER, "1")
    ctx = build_context()
    assert ctx.args == {"seed": 3}
    assert ctx.timeout_seconds == 90
    assert ctx.volume.root == Path("/vol") and ctx.cache_home == Path("/cache")
    assert ctx.cell.is_local_container is True


def test_non_numeric_timeout_is_ignored(job_env: pytest.MonkeyPatch) -> None:
    job_env.setenv(env.TIMEOUT_SECONDS, "soon")
    assert build_context().timeout_seconds is None


@pytest.mark.parametrize(("raw", "message"), [("{nope", "not valid JSON"), ("[1]", "JSON object")])
def test_bad_args_are_refused_clearly(job_env: pytest.MonkeyPatch, raw: str, message: str) -> None:
    job_env.setenv(env.ARGS, raw)
    with pytest.raises(RuntimeError, match=message):
        build_context()


def test_cell_config_fills_the_cell(job_env: pytest.MonkeyPatch) -> None:
    set_config(job_env, {
        "robot_connector_endpoint": ROBOT,
        "operator_call_endpoint": OPERATOR,
        "robot_id": "so101-a",
        "calibration_dir": "/calibration",
        "calibration_file_path": "/calibration/so101-a.json",
        "language_instruction": "pick up the cube",
        "safety_limit": 12.5,
    })
    cell = build_context().cell
    assert cell.robot_port == ROBOT and cell.operator_call_endpoint == OPERATOR
    assert cell.robot_id == "so101-a"
    assert cell.calibration_dir == Path("/calibration")
    assert cell.calibration_file_path == Path("/calibration/so101-a.json")
    assert cell.language_instruction == "pick up the cube"
    assert cell.safety_limit == 12.5


def test_env_vars_win_over_the_cell_config(job_env: pytest.MonkeyPatch) -> None:
    set_config(job_env, {"robot_port": "/dev/ttyACM0", "operator_call_endpoint": "unix:///a.sock",
                         "robot_id": "cfg", "calibration_dir": "/cfg"})
    job_env.setenv(env.CELL_SOCKET, ROBOT)
    job_env.setenv(env.OPERATOR_CALL_ENDPOINT, OPERATOR)
    job_env.setenv(env.ROBOT_ID, "env-id")
    job_env.setenv(env.CALIBRATION_DIR, "/env-cal")
    cell = build_context().cell
    assert (cell.robot_port, cell.operator_call_endpoint) == (ROBOT, OPERATOR)
    assert (cell.robot_id, cell.calibration_dir) == ("env-id", Path("/env-cal"))


@pytest.mark.parametrize(
    ("document", "expected"),
    [
        ({"robot_connector_endpoint": "unix:///a.sock", "connector_socket_path": "/b.sock",
          "robot_port": "/dev/ttyACM0"}, "unix:///a.sock"),
        ({"connector_socket_path": "/b.sock", "robot_port": "/dev/ttyACM0"}, "/b.sock"),
        ({"robot_port": "/dev/ttyACM0"}, "/dev/ttyACM0"),
    ],
)
def test_robot_port_precedence(
    job_env: pytest.MonkeyPatch, document: dict[str, Any], expected: str
) -> None:
    set_config(job_env, document)
    assert build_context().cell.robot_port == expected


def test_bimanual_arms_select_themselves_on_the_cell_endpoint(job_env: pytest.MonkeyPatch) -> None:
    job_env.setenv(env.EMBODIMENT, "lerobot/bimanual_so101")
    set_config(job_env, {
        "robot_connector_endpoint": ROBOT,
        "robot_id": "pair",
        "safety_limit": {"lerobot/bimanual_so101": {"left": 7.0}, "right": 9.0},
        "arms": {
            "left": {"robot_id": "l-id", "calibration_dir": "/cal/l"},
            "right": {"robot_id": "r-id", "calibration_file_path": "/cal/r.json",
                      "robot_port": "tcp://arm-host:7000"},
        },
    })
    cell = build_context().cell
    assert cell.is_bimanual
    assert cell.arm("left") == RuntimeArm(
        name="left", robot_port=f"{ROBOT}?arm=left", robot_id="l-id",
        calibration_dir=Path("/cal/l"), safety_limit=7.0,
    )
    assert cell.arm("right") == RuntimeArm(
        name="right", robot_port="tcp://arm-host:7000", robot_id="r-id",
        calibration_file_path=Path("/cal/r.json"), safety_limit=9.0,
    )
    assert cell.safety_limit is None


def test_per_embodiment_safety_limit_picks_the_jobs_embodiment(job_env: pytest.MonkeyPatch) -> None:
    set_config(job_env, {"safety_limit": {"lerobot/so-101": 4.0, "lerobot/bimanual_so101": 6.0}})
    assert build_context().cell.safety_limit == 4.0


def test_an_arms_own_limit_wins(job_env: pytest.MonkeyPatch) -> None:
    set_config(job_env, {"robot_connector_endpoint": ROBOT, "safety_limit": 10.0,
                         "arms": {"left": {"safety_limit": 3.0}, "right": {}}})
    cell = build_context().cell
    assert (cell.arm("left").safety_limit, cell.arm("right").safety_limit) == (3.0, 10.0)


def test_an_arm_without_port_or_connector_is_refused(job_env: pytest.MonkeyPatch) -> None:
    set_config(job_env, {"robot_port": "/dev/ttyACM0", "arms": {"left": {}}})
    with pytest.raises(RuntimeError, match=r"arms\.left\.robot_port"):
        build_context()


@pytest.mark.parametrize(
    ("document", "field"),
    [
        ({"robot_prot": "x"}, "robot_prot: unknown field"),
        ({"arms": {"left": {"robot_port": 3}}}, "arms.left.robot_port"),
        ({"arms": {"left": {"colour": "red"}}}, "arms.left.colour: unknown field"),
        ({"safety_limit": -1}, "safety_limit"),
        ({"safety_limit": {"left": 0}}, "safety_limit.left must be a positive number"),
        ({"safety_limit": "high"}, "safety_limit"),
        ({"camera_configs": {"front": {"fps": 30}}}, "camera_configs.front.index_or_path"),
        ({"camera_configs": {"front": {"index_or_path": 0, "rotation": 45}}},
         "camera_configs.front.rotation"),
        ({"camera_configs": {"front": {"index_or_path": 0, "color_mode": "hsv"}}},
         "camera_configs.front.color_mode"),
        ({"language_instruction": ["a"]}, "language_instruction"),
    ],
)
def test_malformed_cell_config_names_the_bad_field(document: dict[str, Any], field: str) -> None:
    with pytest.raises(CellConfigError) as info:
        parse_cell_config(json.dumps(document))
    assert field in str(info.value)
    assert str(info.value).startswith("ARMNET_CELL_CONFIG is invalid")


@pytest.mark.parametrize(("raw", "message"), [("{", "not valid JSON"), ("[]", "JSON object")])
def test_cell_config_that_is_not_an_object_is_refused(raw: str, message: str) -> None:
    with pytest.raises(CellConfigError, match=message):
        parse_cell_config(raw)


def test_camera_configs_become_lerobot_opencv_configs() -> None:
    from lerobot.cameras.configs import ColorMode, Cv2Rotation
    from lerobot.cameras.opencv import OpenCVCameraConfig

    config = parse_cell_config(json.dumps({"camera_configs": {
        "front": {"index_or_path": 0, "fps": 30, "width": 640, "height": 480,
                  "color_mode": "bgr", "rotation": 270, "warmup_s": 2},
        "wrist": {"index_or_path": "/dev/video2"},
    }}))
    cameras = build_camera_configs(config.camera_configs)
    front = cameras["front"]
    assert isinstance(front, OpenCVCameraConfig)
    assert (front.index_or_path, front.fps, front.width, front.height) == (0, 30, 640, 480)
    assert front.color_mode is ColorMode.BGR and front.rotation is Cv2Rotation.ROTATE_270
    assert front.warmup_s == 2
    assert str(cameras["wrist"].index_or_path) == "/dev/video2"


def test_camera_configs_are_plain_dicts_without_lerobot(tmp_path: Path) -> None:
    """In a fresh interpreter where lerobot cannot be imported, the SDK falls back to dicts."""
    import subprocess
    import sys

    blocker = tmp_path / "lerobot"
    blocker.mkdir()
    (blocker / "__init__.py").write_text("raise ImportError('lerobot is not installed here')\n")
    code = (
        "import json\n"
        "from armnet_runtime.cell_config import parse_cell_config, build_camera_configs\n"
        "c = parse_cell_config(json.dumps({'camera_configs': {'front': {'index_or_path': 0, 'fps': 30}}}))\n"
        "print(json.dumps(build_camera_configs(c.camera_configs)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True,
        env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"},
    )
    assert json.loads(out.stdout) == {"front": {
        "index_or_path": 0, "fps": 30, "width": None, "height": None, "color_mode": "rgb",
        "rotation": 0, "warmup_s": 1, "fourcc": None,
    }}


def test_secrets_map_each_listed_variable_to_its_value(job_env: pytest.MonkeyPatch) -> None:
    job_env.setenv(env.SECRETS, '["HF_TOKEN", "WANDB_API_KEY"]')
    job_env.setenv("HF_TOKEN", "hf_secret")
    job_env.setenv("WANDB_API_KEY", "wb")
    assert build_context().secrets == {"HF_TOKEN": "hf_secret", "WANDB_API_KEY": "wb"}


@pytest.mark.parametrize(
    ("raw", "message"),
    [('{"HF_TOKEN": "x"}', "JSON list"), ("HF_TOKEN", "not valid JSON"), ('["", "A"]', "JSON list"),
     ("[1]", "JSON list")],
)
def test_malformed_secret_lists_are_refused(
    job_env: pytest.MonkeyPatch, raw: str, message: str
) -> None:
    job_env.setenv(env.SECRETS, raw)
    with pytest.raises(RuntimeError, match=message):
        build_context()


def test_a_listed_secret_that_is_not_set_is_named(job_env: pytest.MonkeyPatch) -> None:
    job_env.setenv(env.SECRETS, '["ARMNET_TEST_MISSING_SECRET"]')
    job_env.delenv("ARMNET_TEST_MISSING_SECRET", raising=False)
    with pytest.raises(RuntimeError, match="ARMNET_TEST_MISSING_SECRET"):
        build_context()


def test_camera_configs_copy_and_rebuild_as_a_dict_does() -> None:
    """Customers copy ``ctx.camera_configs`` or ``dataclasses.asdict`` a dataclass holding it
    (which rebuilds the mapping from its items); either way the cameras survive, whether
    LeRobot is loaded in this process (LeRobot's configs) or not (plain dicts)."""
    import copy
    import dataclasses

    config = parse_cell_config(json.dumps({"camera_configs": {"front": {"index_or_path": 0, "fps": 30}}}))
    cameras = build_camera_configs(config.camera_configs)

    @dataclasses.dataclass
    class Holder:
        cameras: dict[str, Any]

    assert dataclasses.asdict(Holder(cameras))["cameras"]["front"]["fps"] == 30
    assert dataclasses.asdict(Holder(copy.deepcopy(cameras)))["cameras"]["front"]["fps"] == 30
