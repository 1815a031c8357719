"""The shipped images start their entrypoints as the users docs/images.md writes down."""

from __future__ import annotations

import json
from pathlib import Path

import pip
import pytest
from armnet_testbed.images import REPO_ROOT
from armnet_testbed.lockfile import OVERRIDES, overridden, unexcused
from armnet_testbed.plugin import Podman

from tests.images.conftest import run_image

pytestmark = [pytest.mark.container, pytest.mark.timeout(1800)]

ID = ["id"]
OCI_KEYS = ("title", "description", "source", "licenses", "version", "revision", "created",
            "base.name")


def test_operator_image_runs_armnet_operator_help(podman: Podman, operator_image: str) -> None:
    code, output = run_image(podman, operator_image, ["operator", "--help"])

    assert code == 0, output
    assert "usage: armnet operator" in output


def test_operator_image_runs_as_uid_65532_without_extra_groups(
        podman: Podman, operator_image: str) -> None:
    code, output = run_image(podman, operator_image, entrypoint=ID)

    assert code == 0, output
    assert output.strip() == "uid=65532(armnet) gid=65532(armnet) groups=65532(armnet)"


@pytest.mark.parametrize("command", ["agent", "connector", "sim"])
def test_agent_image_runs_each_of_its_commands_help(
        podman: Podman, agent_image: str, command: str) -> None:
    code, output = run_image(podman, agent_image, [command, "--help"])

    assert code == 0, output
    assert f"usage: armnet {command}" in output


def test_agent_image_user_is_in_the_serial_camera_and_usb_groups(
        podman: Podman, agent_image: str) -> None:
    code, output = run_image(podman, agent_image, entrypoint=ID)

    assert code == 0, output
    assert output.strip() == ("uid=65532(armnet) gid=65532(armnet) "
                              "groups=65532(armnet),20(dialout),44(video),46(plugdev)")


def test_agent_image_imports_lerobot_feetech_and_opencv(podman: Podman, agent_image: str) -> None:
    code, output = run_image(podman, agent_image, ["-c", (
        "import cv2, scservo_sdk, lerobot.motors.feetech, lerobot.cameras.opencv; print('ok')")],
        entrypoint=["python"])

    assert code == 0, output
    assert output.strip().endswith("ok")


def test_runtime_image_runs_a_customer_job_built_from_the_example(
        podman: Podman, runtime_image: str) -> None:
    tag = "localhost/armnet-example-job:test"
    podman.client.images.build(path=str(REPO_ROOT / "images" / "example-job"), tag=tag, rm=True,
                               dockerfile="Containerfile",
                               buildargs={"RUNTIME": runtime_image}, network_mode="none")
    try:
        code, output = run_image(podman, tag, environment={
            "ARMNET_JOB_ID": "job-7", "ARMNET_EMBODIMENT": "lerobot/so-101", "ARMNET_TASK": "demo",
            "ARMNET_ARGS": json.dumps({"name": "cell"}), "ARMNET_LOCAL_CONTAINER": "1"})
    finally:
        podman.client.images.remove(tag, force=True)

    assert code == 0, output
    result = next(line for line in output.splitlines() if "[armnet:result]:json" in line)
    assert json.loads(result.split("[armnet:result]:json", 1)[1]) == {
        "greeting": "hello, cell", "job_id": "job-7"}


JOB_ENV = {"ARMNET_LEROBOT_TOOLS": "remote", "ARMNET_CALIBRATION_JOBS": "0"}
"""A job container's environment for LeRobot's tools, as the node agent sets it."""


def test_runtime_lerobot_variant_in_a_job_imports_lerobots_robot_classes_on_the_connectors_bus_as_uid_65532(
        podman: Podman, runtime_lerobot_image: str) -> None:
    """The image's .pth installs the import swap in every interpreter of a job's container.

    One interpreter checks it all: each start imports torch, the longest step of these tests.
    """
    code, output = run_image(podman, runtime_lerobot_image, ["python", "-c", (
        "import os; from lerobot.robots.so_follower import SO101Follower; import lerobot.cameras.opencv; "
        "from lerobot.motors.feetech import FeetechMotorsBus; print(os.getuid(), FeetechMotorsBus.__module__)")],
        environment=JOB_ENV)

    assert code == 0, output
    assert output.strip().splitlines()[-1] == "65532 armnet_runtime.lerobot.remote_feetech"


def test_in_a_job_lerobot_calibrate_is_refused_and_outside_a_job_lerobot_is_untouched(
        podman: Podman, runtime_lerobot_image: str) -> None:
    code, output = run_image(podman, runtime_lerobot_image, [
        "lerobot-calibrate", "--robot.type=so101_follower", "--robot.port=/dev/null", "--robot.id=arm"],
        environment=JOB_ENV)
    assert code == 1, output
    assert "lerobot-calibrate is refused in this job" in output and "EOFError" not in output

    code, output = run_image(podman, runtime_lerobot_image, ["python", "-c", (
        "from lerobot.motors.feetech import FeetechMotorsBus; print(FeetechMotorsBus.__module__)")])
    assert output.strip().splitlines()[-1] == "lerobot.motors.feetech.feetech"  # outside a job: untouched


def test_runtime_image_runs_jobs_as_uid_65532(podman: Podman, runtime_image: str) -> None:
    code, output = run_image(podman, runtime_image, ID)

    assert code == 0, output
    assert output.strip() == "uid=65532(armnet) gid=65532(armnet) groups=65532(armnet)"


@pytest.mark.parametrize("fixture", ["runtime_image", "operator_image", "agent_image"])
def test_every_image_carries_the_oci_labels(
        podman: Podman, fixture: str, request: pytest.FixtureRequest) -> None:
    image = request.getfixturevalue(fixture)
    labels = podman.client.images.get(image).labels

    missing = [k for k in OCI_KEYS if not labels.get(f"org.opencontainers.image.{k}")]
    assert missing == []
    assert labels["org.opencontainers.image.title"] == image.split("/")[-1].split(":")[0]


@pytest.mark.parametrize("fixture", ["runtime_image", "operator_image", "agent_image"])
def test_no_image_ships_pip_or_wheel_in_its_venv_or_a_compiler(
        podman: Podman, fixture: str, request: pytest.FixtureRequest) -> None:
    image = request.getfixturevalue(fixture)
    script = ("import importlib.util, shutil, sys; "
              "print(sys.prefix, importlib.util.find_spec('pip') is None and "
              "importlib.util.find_spec('wheel') is None, "
              "[c for c in ('gcc', 'cc', 'g++', 'make') if shutil.which(c)])")
    code, output = run_image(podman, image, entrypoint=["python", "-c", script])

    assert code == 0, output
    assert output.strip().split(maxsplit=1) == ["/opt/armnet/venv", "True []"]



@pytest.mark.parametrize("fixture", ["runtime_image", "runtime_lerobot_image", "operator_image",
                                     "agent_image"])
def test_pip_check_in_every_image_finds_no_conflict_but_the_declared_exceptions(
        podman: Podman, fixture: str, request: pytest.FixtureRequest) -> None:
    """The images ship no pip: this session's pip is mounted read-only and run by the image's Python."""
    image = request.getfixturevalue(fixture)
    script = ("import sys; sys.path.insert(0, '/opt/pipcheck'); "
              "from pip._internal.cli.main import main; sys.exit(main(['check']))")
    code, output = run_image(
        podman, image, entrypoint=["python", "-c", script],
        environment={"PIP_DISABLE_PIP_VERSION_CHECK": "1"},
        volumes={str(Path(pip.__file__).parent): {"bind": "/opt/pipcheck/pip", "mode": "ro"}})

    assert code in (0, 1), output  # 1: pip found conflicts, which must all be declared ones
    assert unexcused(output, overridden(OVERRIDES.read_text())) == []
