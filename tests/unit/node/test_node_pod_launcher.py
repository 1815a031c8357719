"""The pod launcher's manifest of a job: the plan's env and paths, the simulator's pty for the connector only."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_connector.inputs import LocalOperatorInputs
from armnet_core.api import CELL_RESOURCE_PREFIX, GROUP
from armnet_launch.pod_spec import CONNECTOR_USER, SIDECAR_ENV, SecretRef, device_path
from armnet_node.launchers import PodLauncher, PodSettings, SessionRequest
from armnet_node.metrics import AgentMetrics
from armnet_node.model import parse_cell, parse_job
from armnet_node.plan import HostPaths, plan_launch
from armnet_runtime import env as env_keys
from armnet_sim.presets import SimulatedCell, build_cell

pytestmark = pytest.mark.unit

PATHS = HostPaths(Path("/var/lib/armnet-agent"))
CELL = {"metadata": {"name": "cell-1", "resourceVersion": "7"},
        "spec": {"embodiment": "lerobot/so-101", "nodeName": "host-1", "simulated": True, "task": "pick",
                 "robot": {"robotId": "follower-1", "safetyLimit": 7.5}, "gracePeriodSeconds": 4},
        "status": {"currentJob": "team-a/job-1"}}


def job_obj(**spec: Any) -> dict[str, Any]:
    base: dict[str, Any] = {"image": "localhost/pick:1", "embodiment": "lerobot/so-101", "timeoutSeconds": 60,
                            "args": {"episodes": 3}}
    base.update(spec)
    return {"metadata": {"name": "job-1", "namespace": "team-a", "uid": "uid-1", "resourceVersion": "9"},
            "spec": base, "status": {"phase": "dispatched", "cellName": "cell-1"}}


@pytest.fixture(scope="module")
def sim() -> Iterator[SimulatedCell]:
    cell = build_cell("so101").start()
    try:
        yield cell
    finally:
        cell.stop()


def manifest(sim: SimulatedCell, refs: tuple[SecretRef, ...] = (), simulator_in_pod: bool = False,
             device_plugin: bool = False, connector_user: int = CONNECTOR_USER, **spec: Any) -> dict[str, Any]:
    job, cell = parse_job(job_obj(**spec)), parse_cell(CELL)
    plan = plan_launch(job, cell, PATHS, {})
    settings = PodSettings(node_name="host-1", connector_image="armnet/connector:1", simulator_in_pod=simulator_in_pod,
                           device_plugin=device_plugin, connector_user=connector_user)
    launcher = PodLauncher(None, settings, AgentMetrics())
    request = SessionRequest(job=job, cell=cell, plan=plan, sim=sim, adopted=None, tripped=None,
                             inputs=LocalOperatorInputs(), on_grace_expired=lambda: None, secret_refs=refs)
    return launcher.manifest(request)


def sidecar_config(pod: dict[str, Any]) -> dict[str, Any]:
    (connector,) = pod["spec"]["initContainers"]
    (entry,) = [e for e in connector["env"] if e["name"] == SIDECAR_ENV]
    return dict(json.loads(entry["value"]))


def test_the_connector_reaches_the_simulators_pty_at_its_own_device_path(sim: SimulatedCell) -> None:
    pod = manifest(sim)
    config = sidecar_config(pod)
    assert config["connector"]["arms"]["arm"]["port"] == device_path("arm")
    devices = [v["hostPath"]["path"] for v in pod["spec"]["volumes"] if v.get("hostPath", {}).get("type") == "CharDevice"]
    assert devices == [sim.ports()["arm"]]


def char_devices(pod: dict[str, Any]) -> list[str]:
    return [v["hostPath"]["path"] for v in pod["spec"]["volumes"] if v.get("hostPath", {}).get("type") == "CharDevice"]


def test_an_agent_in_a_pod_has_the_sidecar_run_the_simulator_and_mounts_no_device(sim: SimulatedCell) -> None:
    pod = manifest(sim, simulator_in_pod=True)
    assert sidecar_config(pod)["simulator"] == {"preset": "so101", "latency_ms": 0.0}
    assert char_devices(pod) == []


def test_with_the_simulator_in_the_sidecar_the_connector_requests_no_device_from_the_plugin(sim: SimulatedCell) -> None:
    """The agent's ptys are its own container's then: a bind mount of that path on the host is another terminal."""
    (connector,) = manifest(sim, simulator_in_pod=True, device_plugin=True)["spec"]["initContainers"]
    assert not [name for name in connector["resources"].get("limits", {}) if name.startswith(f"{GROUP}/")]
    assert PodSettings(node_name="h", connector_image="c", device_plugin=True,
                       simulator_in_pod=True).devices_through_plugin(simulated=False)


def test_with_the_simulator_in_the_agent_the_sidecar_config_names_no_simulator(sim: SimulatedCell) -> None:
    assert "simulator" not in sidecar_config(manifest(sim))


def test_the_connector_runs_the_jobs_deadline_itself(sim: SimulatedCell) -> None:
    assert sidecar_config(manifest(sim, timeoutSeconds=45))["connector"]["timeout_seconds"] == 45


def test_the_sidecar_writes_the_cells_calibration_where_the_job_env_points(sim: SimulatedCell) -> None:
    pod = manifest(sim)
    (job,) = pod["spec"]["containers"]
    env = {e["name"]: e.get("value") for e in job["env"]}
    assert env[env_keys.CALIBRATION_FILE_PATH] in sidecar_config(pod)["calibration"]


def test_the_pod_env_names_the_secrets_and_takes_their_values_from_secret_key_refs(sim: SimulatedCell) -> None:
    pod = manifest(sim, (SecretRef("API_TOKEN", "api-token", "API_TOKEN"),), secrets={"API_TOKEN": "api-token"})
    (job,) = pod["spec"]["containers"]
    env = {e["name"]: e for e in job["env"]}
    assert json.loads(env[env_keys.SECRETS]["value"]) == ["API_TOKEN"]
    assert env["API_TOKEN"]["valueFrom"]["secretKeyRef"] == {"name": "api-token", "key": "API_TOKEN"}


def test_the_pod_is_named_after_the_job_uid_in_the_jobs_namespace(sim: SimulatedCell) -> None:
    meta = manifest(sim)["metadata"]
    assert (meta["name"], meta["namespace"]) == ("armnet-uid-1", "team-a")


def test_with_the_device_plugin_the_pod_requests_the_cells_resource_instead_of_mounting_the_pty(
    sim: SimulatedCell,
) -> None:
    job, cell = parse_job(job_obj()), parse_cell(CELL)
    settings = PodSettings(node_name="host-1", connector_image="armnet/connector:1", device_plugin=True)
    request = SessionRequest(job=job, cell=cell, plan=plan_launch(job, cell, PATHS, {}), sim=sim, adopted=None,
                             tripped=None, inputs=LocalOperatorInputs(), on_grace_expired=lambda: None)
    pod = PodLauncher(None, settings, AgentMetrics()).manifest(request)
    (connector,) = pod["spec"]["initContainers"]
    assert connector["resources"]["limits"][f"{CELL_RESOURCE_PREFIX}cell-1"] == "1"
    assert not [v for v in pod["spec"]["volumes"] if v.get("hostPath", {}).get("type") == "CharDevice"]
    assert sidecar_config(pod)["connector"]["arms"]["arm"]["port"] == device_path("arm")


def test_the_connector_runs_as_the_agents_connector_user(sim: SimulatedCell) -> None:
    (default,) = manifest(sim)["spec"]["initContainers"]
    (chosen,) = manifest(sim, connector_user=1001)["spec"]["initContainers"]
    assert (default["securityContext"]["runAsUser"], default["securityContext"]["runAsNonRoot"]) == (65532, True)
    assert (chosen["securityContext"]["runAsUser"], chosen["securityContext"]["runAsNonRoot"]) == (1001, True)
