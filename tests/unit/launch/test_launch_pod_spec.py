"""A job's pod: the connector as a native sidecar, devices for it alone, a locked-down customer container."""

from __future__ import annotations

import json
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from armnet_core.api import API_VERSION, CELL_RESOURCE_PREFIX, GROUP
from armnet_launch.plan import LABEL_CELL, LABEL_JOB_UID
from armnet_launch.pod_spec import (
    ANNOTATION_CELL,
    ANNOTATION_JOB,
    CONNECTOR_CONTAINER,
    CONNECTOR_USER,
    DEADLINE_MARGIN_S,
    JOB_CONTAINER,
    SIDECAR_ENV,
    START_ALLOWANCE_S,
    PodInputs,
    SecretRef,
    active_deadline_seconds,
    build_pod,
    device_path,
    running_deadline_seconds,
    serving_gate,
)

pytestmark = pytest.mark.unit

SOCKETS = "/var/lib/armnet/run/uid-1/sockets"
#: What the node agent's device plugin serves for cell-1.
CELL_1_RESOURCE = f"{CELL_RESOURCE_PREFIX}cell-1"


def inputs(**changes: Any) -> PodInputs:
    base: dict[str, Any] = {
        "name": "armnet-uid-1", "namespace": "team-a", "node_name": "robot-host-1",
        "job_name": "pick-1", "job_uid": "uid-1",
        "labels": {LABEL_CELL: "cell-1", LABEL_JOB_UID: "uid-1"},
        "job_image": "registry.example/pick:1", "job_env": {"ARMNET_JOB_ID": "uid-1"},
        "connector_image": "armnet/connector:1", "connector_command": ("python3", "-m", "armnet_launch.sidecar"),
        "sidecar": {"socket_dir": SOCKETS, "connector": {"arms": {}}, "calibration": {}},
        "socket_dir": SOCKETS, "calibration_dir": "/var/lib/armnet/run/uid-1/calibration",
        "cache_dir": "/var/lib/armnet/cells/cell-1/cache", "volume_dir": "/var/lib/armnet/volumes/team-a",
        "timeout_seconds": 600, "grace_seconds": 10,
        "devices": {"arm": "/dev/serial/by-id/usb-feetech-1"},
    }
    base.update(changes)
    return PodInputs(**base)


def containers(pod: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    (connector,) = pod["spec"]["initContainers"]
    (job,) = pod["spec"]["containers"]
    return connector, job


def mounted_volumes(container: dict[str, Any], pod: dict[str, Any]) -> list[dict[str, Any]]:
    names = {m["name"] for m in container["volumeMounts"]}
    return [v for v in pod["spec"]["volumes"] if v["name"] in names]


def test_the_connector_is_a_native_sidecar_whose_post_start_gate_waits_for_its_socket() -> None:
    connector, _ = containers(build_pod(inputs()))
    assert connector["name"] == CONNECTOR_CONTAINER
    assert connector["restartPolicy"] == "Always"
    assert connector["lifecycle"]["postStart"]["exec"]["command"] == serving_gate(f"{SOCKETS}/robot.sock")
    assert "startupProbe" not in connector  # sampled once a second: the gate alone orders the start
    assert connector["readinessProbe"]["exec"]["command"] == ["test", "-S", f"{SOCKETS}/robot.sock"]


def test_the_serving_gate_returns_once_the_socket_is_bound(tmp_path: Path) -> None:
    path = tmp_path / "robot.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    binder = threading.Timer(0.3, listener.bind, (str(path),))
    started = time.monotonic()
    binder.start()
    try:
        done = subprocess.run(serving_gate(str(path), wait_s=10), capture_output=True, text=True, timeout=20)
    finally:
        binder.join()
        listener.close()
    assert done.returncode == 0, done.stderr
    assert 0.3 <= time.monotonic() - started < 5


def test_the_serving_gate_fails_with_a_reason_when_the_connector_never_serves(tmp_path: Path) -> None:
    (tmp_path / "robot.sock").write_text("")  # a plain file is not a socket
    done = subprocess.run(serving_gate(str(tmp_path / "robot.sock"), wait_s=1, poll_s=0.1),
                          capture_output=True, text=True, timeout=20)
    assert done.returncode == 1
    assert f"the connector did not serve {tmp_path}/robot.sock within 1 s" in done.stderr


def test_both_containers_share_the_sockets_in_a_memory_backed_empty_dir() -> None:
    pod = build_pod(inputs())
    volumes = {v["name"]: v for v in pod["spec"]["volumes"]}
    assert volumes["sockets"]["emptyDir"]["medium"] == "Memory"
    for container in containers(pod):
        assert {"name": "sockets", "mountPath": SOCKETS} in container["volumeMounts"]


def test_the_device_is_mounted_into_the_connector_only() -> None:
    pod = build_pod(inputs())
    connector, job = containers(pod)
    connector_devices = [v for v in mounted_volumes(connector, pod) if v.get("hostPath", {}).get("type") == "CharDevice"]
    assert [v["hostPath"]["path"] for v in connector_devices] == ["/dev/serial/by-id/usb-feetech-1"]
    assert device_path("arm") in {m["mountPath"] for m in connector["volumeMounts"]}
    assert not [v for v in mounted_volumes(job, pod) if v.get("hostPath", {}).get("type") == "CharDevice"]
    assert not [m for m in job["volumeMounts"] if m["mountPath"].startswith("/dev")]


def test_the_observer_socket_volume_is_mounted_into_the_connector_only() -> None:
    pod = build_pod(inputs(observer_dir="/run/armnet-observer"))
    connector, job = containers(pod)
    volumes = {v["name"]: v for v in pod["spec"]["volumes"]}
    assert volumes["observer"]["emptyDir"]["medium"] == "Memory"
    assert {"name": "observer", "mountPath": "/run/armnet-observer"} in connector["volumeMounts"]
    assert "observer" not in {m["name"] for m in job["volumeMounts"]}


@pytest.mark.parametrize(("field", "path", "volume", "kind", "owner"), [
    # The job's output: the job writes it, the connector never sees it.
    ("output_dir", "/var/lib/armnet/outputs/uid-1", "output", "DirectoryOrCreate", "job"),
    # The cell's record of the job: the connector's alone (the agent makes it and hands it to the
    # connector's uid before the pod: type Directory, never created by the kubelet).
    ("record_dir", "/var/lib/armnet/records/uid-1", "cell-record", "Directory", "connector"),
])
def test_a_host_directory_of_one_container_is_mounted_into_that_container_only(
        field: str, path: str, volume: str, kind: str, owner: str) -> None:
    pod = build_pod(inputs(**{field: path}))
    connector, job = containers(pod)
    mine, other = (job, connector) if owner == "job" else (connector, job)
    volumes = {v["name"]: v for v in pod["spec"]["volumes"]}
    assert volumes[volume]["hostPath"] == {"path": path, "type": kind}
    assert {"name": volume, "mountPath": path} in mine["volumeMounts"]
    assert volume not in {m["name"] for m in other["volumeMounts"]}
    assert volume not in {v["name"] for v in build_pod(inputs())["spec"]["volumes"]}


def test_the_completion_monitors_host_files_are_mounted_read_only_into_the_connector_only_at_their_paths() -> None:
    files = ("/var/lib/armnet/models/reach.onnx", "/var/lib/armnet/secrets/judge-token")
    pod = build_pod(inputs(host_files=files))
    connector, job = containers(pod)
    volumes = {v["name"]: v for v in pod["spec"]["volumes"]}
    for i, path in enumerate(files):
        assert volumes[f"host-file-{i}"]["hostPath"] == {"path": path, "type": "File"}
        assert {"name": f"host-file-{i}", "mountPath": path, "readOnly": True} in connector["volumeMounts"]
    assert not [m for m in job["volumeMounts"] if m["name"].startswith("host-file-")]
    assert not [v for v in build_pod(inputs())["spec"]["volumes"] if v["name"].startswith("host-file-")]


def test_without_an_observer_directory_there_is_no_observer_volume() -> None:
    assert "observer" not in {v["name"] for v in build_pod(inputs())["spec"]["volumes"]}


def test_the_customer_container_is_non_root_without_privileges_and_with_a_read_only_root() -> None:
    _, job = containers(build_pod(inputs()))
    context = job["securityContext"]
    assert context["runAsNonRoot"] is True and context["runAsUser"] != 0
    assert context["allowPrivilegeEscalation"] is False and context["privileged"] is False
    assert context["readOnlyRootFilesystem"] is True
    assert context["capabilities"] == {"drop": ["ALL"]}
    assert {"name": "job-tmp", "mountPath": "/tmp"} in job["volumeMounts"]


def test_the_connector_runs_as_the_non_root_user_the_pod_names_not_its_images() -> None:
    """``agent.connectorImage`` may be any image: the pod itself keeps the device holder off root."""
    connector, _ = containers(build_pod(inputs(connector_image="registry.example/anything:latest")))
    context = connector["securityContext"]
    assert context["runAsNonRoot"] is True
    assert context["runAsUser"] == CONNECTOR_USER != 0
    assert "runAsGroup" not in context, "a group would drop the image user's device groups (dialout, video)"
    assert context["allowPrivilegeEscalation"] is False and context["privileged"] is False
    assert context["capabilities"] == {"drop": ["ALL"]}


def test_a_root_connector_is_only_what_the_agent_asks_for_explicitly() -> None:
    """Development stand-in images: ``--connector-user 0``; never the image's USER deciding it."""
    connector, _ = containers(build_pod(inputs(connector_user=0)))
    assert (connector["securityContext"]["runAsUser"], connector["securityContext"]["runAsNonRoot"]) == (0, False)


def test_the_calibration_is_read_only_for_the_customer_and_written_by_the_connector() -> None:
    connector, job = containers(build_pod(inputs()))
    calibration = [m for m in job["volumeMounts"] if m["name"] == "calibration"]
    assert calibration[0]["readOnly"] is True
    assert not [m for m in connector["volumeMounts"] if m["name"] == "calibration" and m.get("readOnly")]


def test_the_pod_uses_no_host_namespace_and_mounts_no_service_account_token() -> None:
    spec = build_pod(inputs())["spec"]
    assert spec["hostNetwork"] is False and spec["hostPID"] is False and spec["hostIPC"] is False
    assert spec["automountServiceAccountToken"] is False


def test_the_pod_never_restarts_and_runs_on_the_agents_own_node() -> None:
    spec = build_pod(inputs())["spec"]
    assert spec["restartPolicy"] == "Never"
    assert spec["nodeName"] == "robot-host-1"


def test_a_new_pods_deadline_is_its_run_window_plus_room_to_start() -> None:
    """The kubelet counts from the pod's start, image pulls included: a slow pull must not end a healthy job."""
    assert build_pod(inputs())["spec"]["activeDeadlineSeconds"] == 600 + 10 + DEADLINE_MARGIN_S + START_ALLOWANCE_S
    assert active_deadline_seconds(60, 2.5) == 60 + 3 + DEADLINE_MARGIN_S + START_ALLOWANCE_S


def test_once_the_job_runs_its_deadline_is_timeout_plus_grace_plus_a_margin_from_its_own_start() -> None:
    assert running_deadline_seconds(60, 2.5, job_started_after_s=41.2) == 42 + 60 + 3 + DEADLINE_MARGIN_S
    assert running_deadline_seconds(60, 2.5, job_started_after_s=0.0) == 60 + 3 + DEADLINE_MARGIN_S


def test_a_running_deadline_never_extends_the_first() -> None:
    """The API lets activeDeadlineSeconds only decrease: a start slower than the allowance keeps the first."""
    assert running_deadline_seconds(60, 2.5, job_started_after_s=5000) == active_deadline_seconds(60, 2.5)


def test_the_robotjob_owns_the_pod() -> None:
    (owner,) = build_pod(inputs())["metadata"]["ownerReferences"]
    assert owner == {"apiVersion": API_VERSION, "kind": "RobotJob", "name": "pick-1", "uid": "uid-1",
                     "controller": True, "blockOwnerDeletion": False}


def test_labels_and_annotations_tie_the_pod_to_its_cell_and_job() -> None:
    meta = build_pod(inputs())["metadata"]
    assert meta["labels"][LABEL_CELL] == "cell-1" and meta["labels"][LABEL_JOB_UID] == "uid-1"
    assert meta["annotations"][ANNOTATION_JOB] == "team-a/pick-1"
    assert meta["annotations"][ANNOTATION_CELL] == "cell-1"
    assert meta["namespace"] == "team-a"


def test_secrets_are_secret_key_refs_and_no_value_is_in_the_pod() -> None:
    pod = build_pod(inputs(secrets=(SecretRef("API_TOKEN", "api-token", "token"),)))
    _, job = containers(pod)
    (entry,) = [e for e in job["env"] if e["name"] == "API_TOKEN"]
    assert entry == {"name": "API_TOKEN", "valueFrom": {"secretKeyRef": {"name": "api-token", "key": "token"}}}


def test_the_sidecar_gets_its_configuration_as_one_json_env_var() -> None:
    connector, job = containers(build_pod(inputs()))
    (entry,) = [e for e in connector["env"] if e["name"] == SIDECAR_ENV]
    assert json.loads(entry["value"])["socket_dir"] == SOCKETS
    assert SIDECAR_ENV not in {e["name"] for e in job["env"]}


def test_the_customer_container_runs_the_images_own_command_unless_one_is_given() -> None:
    _, job = containers(build_pod(inputs()))
    assert "command" not in job and job["name"] == JOB_CONTAINER
    _, job = containers(build_pod(inputs(job_command=("armnet-runtime", "/job/main.py"))))
    assert job["command"] == ["armnet-runtime", "/job/main.py"]


def test_resources_have_requests_and_a_memory_limit() -> None:
    _, job = containers(build_pod(inputs()))
    assert set(job["resources"]["requests"]) == {"cpu", "memory"}
    assert "memory" in job["resources"]["limits"]


def test_development_mounts_are_read_only_in_both_containers() -> None:
    pod = build_pod(inputs(dev_mounts=("/opt/venv",)))
    for container in containers(pod):
        assert {"name": "dev-0", "mountPath": "/opt/venv", "readOnly": True} in container["volumeMounts"]


def test_with_the_device_plugin_the_connector_requests_the_cells_resource_and_no_device_volume_exists() -> None:
    pod = build_pod(inputs(device_resource=CELL_1_RESOURCE))
    connector, job = containers(pod)
    assert connector["resources"]["requests"][CELL_1_RESOURCE] == "1"
    assert connector["resources"]["limits"][CELL_1_RESOURCE] == "1"
    assert not [v for v in pod["spec"]["volumes"] if v.get("hostPath", {}).get("type") == "CharDevice"]
    assert not [m for m in connector["volumeMounts"] if m["mountPath"].startswith("/dev")]
    assert connector["securityContext"]["privileged"] is False


def test_with_the_device_plugin_the_customer_container_requests_no_device_resource() -> None:
    _, job = containers(build_pod(inputs(device_resource=CELL_1_RESOURCE)))
    for section in job["resources"].values():
        assert not [name for name in section if name.startswith(f"{GROUP}/")]
