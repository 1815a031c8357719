"""The client against the real kube-apiserver, as a tenant: submit, get, list, cancel, cells, RBAC.

No operator runs here: jobs stay unphased (``submitted``), which is what a
tenant sees before the operator binds them. Nothing fakes the agent: no test
writes a terminal phase and then claims a job ran. Each tenant is a fresh
client-certificate identity granted by a Role in its own namespace.
"""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_cli.main import main as armnet
from armnet_client import (
    Client,
    ClusterUnreachable,
    CrdsMissing,
    Forbidden,
    InvalidJob,
    JobNotFound,
    NamespaceNotFound,
    NoClusterConfigured,
)
from armnet_client.kube import translate
from armnet_core.api import API_VERSION, CELLS, GROUP, ROBOTJOBS, VERSION
from armnet_core.models import JobSpec, JobStatus
from kubernetes import client as kclient
from kubernetes.client.exceptions import ApiException

from tests.integration.client_bed import Tenant

pytestmark = pytest.mark.integration



@pytest.fixture
def tenant(k8s: Any, namespace: str) -> Tenant:
    return Tenant(k8s, namespace)


SPEC = JobSpec(image="localhost/pick:dev", embodiment="test/client", task="pick-cube",
               args={"episodes": 2}, timeout_seconds=90, secrets={"HF_TOKEN": "hf-token"})


def test_submit_creates_the_robotjob_with_the_spec_mapped_one_to_one(k8s: Any, tenant: Tenant) -> None:
    job = tenant.client().submit(SPEC, name="pick-1")

    stored = kclient.CustomObjectsApi(k8s.api_client()).get_namespaced_custom_object(
        GROUP, VERSION, tenant.namespace, ROBOTJOBS, "pick-1")
    assert job.id == "pick-1" and job.status is JobStatus.SUBMITTED
    assert {k: stored["spec"][k] for k in ("image", "embodiment", "task", "args", "timeoutSeconds",
                                           "secrets", "detach")} == {
        "image": "localhost/pick:dev", "embodiment": "test/client", "task": "pick-cube",
        "args": {"episodes": 2}, "timeoutSeconds": 90, "secrets": {"HF_TOKEN": "hf-token"},
        "detach": False}


def test_get_reads_back_the_same_spec_and_a_generated_name_when_none_is_given(tenant: Tenant) -> None:
    client = tenant.client()
    job = client.submit(SPEC)

    again = client.get(job.id)

    assert job.id.startswith("pick-") and again.id == job.id
    assert again.spec == SPEC
    assert again.status is JobStatus.SUBMITTED and again.result is None


def test_cancel_sets_spec_cancel_once(k8s: Any, tenant: Tenant) -> None:
    client = tenant.client()
    client.submit(SPEC, name="to-cancel")

    client.cancel("to-cancel")
    client.cancel("to-cancel")

    stored = kclient.CustomObjectsApi(k8s.api_client()).get_namespaced_custom_object(
        GROUP, VERSION, tenant.namespace, ROBOTJOBS, "to-cancel")
    assert stored["spec"]["cancel"] is True


def test_a_missing_job_is_job_not_found_naming_the_namespace(tenant: Tenant) -> None:
    with pytest.raises(JobNotFound, match=f"'nope' not found in namespace '{tenant.namespace}'"):
        tenant.client().get("nope")


def test_the_cluster_refusal_of_a_bad_spec_is_invalid_job_with_its_reason(tenant: Tenant) -> None:
    bad = JobSpec(image="Not An Image!", embodiment="test/client")

    with pytest.raises(InvalidJob, match="image must be an image reference"):
        tenant.client().submit(bad, name="bad")


def test_a_tenant_cannot_read_or_cancel_another_namespaces_jobs(k8s: Any, namespace: str) -> None:
    owner = Tenant(k8s, namespace)
    owner.client().submit(SPEC, name="private")
    other_ns = k8s.create_namespace("other")
    try:
        intruder = Tenant(k8s, other_ns)
        looking = intruder.client(namespace=namespace)

        with pytest.raises(Forbidden, match=f"may not get robotjobs in namespace '{namespace}'"):
            looking.get("private")
        with pytest.raises(Forbidden, match=f"may not cancel robotjobs in namespace '{namespace}'"):
            looking.cancel("private")
        with pytest.raises(Forbidden, match="may not list robotjobs"):
            looking.list_jobs()
    finally:
        k8s.delete_namespace(other_ns)
    assert owner.client().get("private").status is JobStatus.SUBMITTED


def test_a_namespace_that_does_not_exist_is_named_as_missing_by_submit_and_get(
    k8s: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    admin = Client(kubeconfig=str(k8s.kubeconfig), namespace="no-such-namespace", env={})
    with pytest.raises(NamespaceNotFound, match="namespace 'no-such-namespace' does not exist on this cluster"):
        admin.submit(SPEC, name="nowhere")
    with pytest.raises(NamespaceNotFound):
        admin.list_jobs()

    where = ["--kubeconfig", str(k8s.kubeconfig), "-n", "no-such-namespace"]
    assert armnet(["submit", "--detach", "--image", "localhost/pick:dev", "--embodiment", "test/client", *where]) == 1
    assert armnet(["get", *where]) == 1
    errors = capsys.readouterr().err.splitlines()
    assert [line.split(":", 1)[0] for line in errors] == ["error", "error"]
    assert all("namespace 'no-such-namespace' does not exist" in line and "CRD" not in line for line in errors)


def test_an_empty_namespace_that_exists_still_lists_no_jobs(
    k8s: Any, tenant: Tenant, capsys: pytest.CaptureFixture[str]
) -> None:
    assert Client(kubeconfig=str(k8s.kubeconfig), namespace=tenant.namespace, env={}).list_jobs() == []
    assert tenant.cli("get") == 0  # a tenant may not read namespaces: its own empty list stands
    assert capsys.readouterr().out.strip() == f"No RobotJobs in namespace {tenant.namespace}."


def test_a_resource_the_cluster_does_not_serve_is_crds_missing(k8s: Any) -> None:
    api = kclient.CustomObjectsApi(k8s.api_client())
    with pytest.raises(ApiException) as refused:
        api.list_namespaced_custom_object(f"absent.{GROUP}", VERSION, "default", "robotjobs")

    error = translate(refused.value.status or 0, refused.value.body, verb="list", resource="robotjobs",
                      namespace="default")

    assert isinstance(error, CrdsMissing) and "the armnet CRDs are not installed" in str(error)


def test_an_explicit_missing_kubeconfig_is_no_cluster_configured(tmp_path: Path) -> None:
    with pytest.raises(NoClusterConfigured, match="does not exist"):
        Client(kubeconfig=str(tmp_path / "nope"), env={}).get("x")


def test_cells_lists_phase_job_failing_conditions_and_heartbeat(k8s: Any, tenant: Tenant) -> None:
    name = f"cell-{uuid.uuid4().hex[:6]}"
    api = kclient.CustomObjectsApi(k8s.api_client())
    api.create_cluster_custom_object(GROUP, VERSION, CELLS, {
        "apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name},
        "spec": {"embodiment": "test/client", "nodeName": "host-1"}})
    api.patch_cluster_custom_object_status(GROUP, VERSION, CELLS, name, {"status": {
        "phase": "Faulted", "lastHeartbeatTime": "2026-11-24T10:00:00Z", "conditions": [
            {"type": "AgentConnected", "status": "True", "reason": "Heartbeat"},
            {"type": "HardwareReady", "status": "False", "reason": "DeviceLost"}]}})
    try:
        cells = {c.name: c for c in tenant.client().cells()}
    finally:
        api.delete_cluster_custom_object(GROUP, VERSION, CELLS, name)

    cell = cells[name]
    assert (cell.phase, cell.embodiment) == ("Faulted", "test/client")
    assert [c.type for c in cell.false_conditions] == ["HardwareReady"]
    assert cell.last_heartbeat is not None
    assert cell.completion is None


def test_wide_cells_show_the_completion_monitor_the_cell_was_given(
    k8s: Any, tenant: Tenant, capsys: pytest.CaptureFixture[str]
) -> None:
    name = f"cell-{uuid.uuid4().hex[:6]}"
    api = kclient.CustomObjectsApi(k8s.api_client())
    api.create_cluster_custom_object(GROUP, VERSION, CELLS, {  # the CRD's own validation accepts it
        "apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name},
        "spec": {"embodiment": "test/client", "nodeName": "host-1", "cameras": {"top": {"indexOrPath": 0}},
                 "completion": {"scorer": "region", "camera": "top", "arucoId": 7,
                                "region": {"left": 0.1, "top": 0.1, "width": 0.5, "height": 0.5}}}})
    try:
        capsys.readouterr()
        assert tenant.cli("cells", "-o", "wide") == 0
        row = next(line.split() for line in capsys.readouterr().out.splitlines() if line.startswith(name))
    finally:
        api.delete_cluster_custom_object(GROUP, VERSION, CELLS, name)
    assert row[-2:] == ["host-1", "region(top)"]


def test_the_cli_submits_gets_and_cancels_with_kubectl_like_exit_codes(
    tenant: Tenant, capsys: pytest.CaptureFixture[str]
) -> None:
    assert tenant.cli("submit", "--detach", "--name", "cli-1", "--image", "localhost/pick:dev",
                      "--embodiment", "test/client", "--args", '{"a": 1}') == 0
    assert capsys.readouterr().out.strip() == "cli-1"

    assert tenant.cli("get") == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].split() == ["NAME", "STATUS", "CELL", "EMBODIMENT", "QUEUE", "AGE"]
    assert table[1].split()[:4] == ["cli-1", "submitted", "<none>", "test/client"]

    assert tenant.cli("result", "cli-1") == 2
    assert "not finished" in capsys.readouterr().out

    assert tenant.cli("cancel", "cli-1") == 0
    assert tenant.cli("get", "cli-1", "-o", "json") == 0
    assert '"cancelRequested": true' in capsys.readouterr().out

    assert tenant.cli("get", "missing") == 1
    assert "error: robotjob 'missing' not found" in capsys.readouterr().err
    assert tenant.cli("result", "missing") == 3


def test_submit_from_a_manifest_keeps_fields_the_sdk_spec_lacks(
    k8s: Any, tenant: Tenant, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest = tmp_path / "job.yaml"
    manifest.write_text(yaml.safe_dump({
        "apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": "from-file"},
        "spec": {"image": "localhost/pick:dev", "embodiment": "test/client", "priority": 5}}))

    assert tenant.cli("submit", "-f", str(manifest), "--detach") == 0

    stored = kclient.CustomObjectsApi(k8s.api_client()).get_namespaced_custom_object(
        GROUP, VERSION, tenant.namespace, ROBOTJOBS, "from-file")
    assert (stored["spec"]["priority"], stored["spec"]["detach"]) == (5, True)
    assert capsys.readouterr().out.strip() == "from-file"


def test_submit_flags_set_a_preflight_and_a_priority_over_the_sdks_spec(
    k8s: Any, tenant: Tenant, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert tenant.cli("submit", "--detach", "--name", "checked", "--image", "localhost/pick:dev",
                      "--embodiment", "test/client", "--timeout", "300", "--preflight", "45",
                      "--priority", "3") == 0
    assert capsys.readouterr().out.strip() == "checked"
    stored = kclient.CustomObjectsApi(k8s.api_client()).get_namespaced_custom_object(
        GROUP, VERSION, tenant.namespace, ROBOTJOBS, "checked")
    spec = stored["spec"]
    assert (spec["preflight"], spec["priority"], spec["timeoutSeconds"], spec["detach"]) == (
        {"seconds": 45}, 3, 300, True)

    manifest = tmp_path / "job.yaml"
    manifest.write_text(yaml.safe_dump({
        "apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": "from-file-checked"},
        "spec": {"image": "localhost/pick:dev", "embodiment": "test/client", "priority": 5}}))
    assert tenant.cli("submit", "-f", str(manifest), "--detach", "--preflight", "20") == 0
    stored = kclient.CustomObjectsApi(k8s.api_client()).get_namespaced_custom_object(
        GROUP, VERSION, tenant.namespace, ROBOTJOBS, "from-file-checked")
    assert (stored["spec"]["preflight"], stored["spec"]["priority"]) == ({"seconds": 20}, 5)


def test_an_apiserver_that_does_not_answer_is_cluster_unreachable_naming_the_server(tmp_path: Path) -> None:
    kubeconfig = tmp_path / "kubeconfig"
    kubeconfig.write_text(yaml.safe_dump({
        "apiVersion": "v1", "kind": "Config", "current-context": "gone",
        "clusters": [{"name": "c", "cluster": {"server": "https://127.0.0.1:1"}}],
        "users": [{"name": "u", "user": {"token": "t"}}],
        "contexts": [{"name": "gone", "context": {"cluster": "c", "user": "u"}}]}))

    with pytest.raises(ClusterUnreachable, match="cannot reach the cluster at https://127.0.0.1:1"):
        Client(kubeconfig=str(kubeconfig), env={}).get("x")
