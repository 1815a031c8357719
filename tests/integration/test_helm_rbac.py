"""The chart's RBAC, applied to the real API server and exercised with real identities.

The operator and agent act with real service-account tokens (TokenRequest) of the
accounts the chart creates; the tenant is a real user (client certificate) bound the
way a platform team binds `edit` in its namespace. The test bed has no
controller-manager, so ClusterRole aggregation into edit/view does not happen here:
the tenant is bound to the chart's tenant ClusterRole directly (its aggregation labels
are checked in test_helm_chart.py).
"""

from __future__ import annotations

import json
import subprocess
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_core.api import CELL_RESOURCE_PREFIX, MANAGED_BY_LABEL
from armnet_launch.plan import (
    LABEL_CELL,
    LABEL_JOB_UID,
    LABEL_MANAGED_BY,
    LABEL_NAME,
    LABEL_NAMESPACE,
    MANAGED_BY_AGENT,
)
from armnet_launch.pod_spec import PodInputs, build_pod
from armnet_node.plan import container_name
from armnet_testbed.kube import ControlPlane, KubeUser

from tests.support.helm import render

pytestmark = pytest.mark.integration

RBAC_KINDS = {"ServiceAccount", "ClusterRole", "ClusterRoleBinding", "Role", "RoleBinding",
              "ValidatingAdmissionPolicy", "ValidatingAdmissionPolicyBinding"}
CLUSTER_KINDS = {"ClusterRole", "ClusterRoleBinding", "ValidatingAdmissionPolicy", "ValidatingAdmissionPolicyBinding"}
JOB_SECRET = "job-token"
OTHER_SECRET = "other-token"
MODEL_CONFIGMAP = "reach-classifier"


@dataclass(frozen=True)
class Release:
    plane: ControlPlane
    fullname: str
    namespace: str  # where the chart is installed
    team_a: str  # a job namespace whose jobs may use JOB_SECRET
    team_b: str  # another job namespace
    operator: Path  # kubeconfig with the operator account's token
    agent: Path
    tenant_a: KubeUser  # edit in team_a, cell reader cluster-wide
    editor: KubeUser  # the built-in edit role's own rules (pods, exec, ...) in team_a

    def as_(self, who: Path | KubeUser, *args: str, input: str | None = None) -> subprocess.CompletedProcess[str]:
        """kubectl as ``who``; never raises, the caller asserts on the outcome."""
        kubeconfig = who.kubeconfig if isinstance(who, KubeUser) else who
        return subprocess.run([self.plane.kubectl_path, f"--kubeconfig={kubeconfig}", *args], input=input,
                              capture_output=True, text=True, timeout=60, check=False)

    def can(self, who: Path | KubeUser, verb: str, resource: str, namespace: str | None = None, *,
            subresource: str | None = None) -> bool:
        """`kubectl auth can-i` as ``who``; ``resource`` may be ``kind/name`` (a subresource
        needs ``subresource=``: ``robotjobs/status`` would mean the RobotJob named status)."""
        scope = ["-n", namespace] if namespace else ["--all-namespaces"]
        sub = [f"--subresource={subresource}"] if subresource else []
        result = self.as_(who, "auth", "can-i", verb, resource, *scope, *sub)
        return result.stdout.strip() == "yes"


def forbidden(result: subprocess.CompletedProcess[str]) -> bool:
    return result.returncode != 0 and "Forbidden" in result.stderr


def token_kubeconfig(plane: ControlPlane, account: str, namespace: str, path: Path, *,
                     bound_pod: str | None = None) -> Path:
    """A kubeconfig carrying a real, short-lived token of ``account`` (TokenRequest); bound to
    ``bound_pod`` it carries that pod's node, like the token the kubelet gives a pod."""
    bound = ["--bound-object-kind=Pod", f"--bound-object-name={bound_pod}"] if bound_pod else []
    token = plane.kubectl("create", "token", account, "-n", namespace, "--duration=1h", *bound).stdout.strip()
    config = yaml.safe_load(plane.kubeconfig.read_text())
    config["users"] = [{"name": account, "user": {"token": token}}]
    for context in config["contexts"]:
        context["context"]["user"] = account
    path.write_text(yaml.safe_dump(config))
    path.chmod(0o600)
    return path


def robotjob(name: str, **spec: Any) -> str:
    return json.dumps({"apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob", "metadata": {"name": name},
                       "spec": {"image": "localhost/job:dev", "embodiment": "lerobot/so-101", **spec}})


def secret(name: str) -> str:
    return json.dumps({"apiVersion": "v1", "kind": "Secret", "metadata": {"name": name},
                       "stringData": {"value": f"{name}-value"}})


@pytest.fixture(scope="module")
def release(k8s: ControlPlane, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Release]:
    suffix = uuid.uuid4().hex[:6]
    namespace, team_a, team_b = (k8s.create_namespace(p) for p in ("helm-rbac", "team-a", "team-b"))
    tenants = f"armnet:helm-tenants-{suffix}"
    objects = [o for o in render(f"rbac-{suffix}", namespace, values={
        "crds": {"install": False},
        "jobNamespaces": [{"name": team_a, "secrets": [JOB_SECRET]}, {"name": team_b}],
        "rbac": {"tenants": {"cellReaderGroups": [tenants]}},
        "agent": {"nodeBoundPods": True, "completionFiles": {"configMaps": [MODEL_CONFIGMAP]}},
    }) if o["kind"] in RBAC_KINDS]
    manifest = yaml.safe_dump_all(objects)
    fullname = f"rbac-{suffix}-armnet"
    cluster_objects = [f"{o['kind'].lower()}/{o['metadata']['name']}" for o in objects
                       if o["kind"] in CLUSTER_KINDS]
    k8s.kubectl("apply", "-f", "-", input=manifest)
    try:
        for ns, name in ((team_a, JOB_SECRET), (team_a, OTHER_SECRET), (team_b, JOB_SECRET)):
            k8s.kubectl("apply", "-n", ns, "-f", "-", input=secret(name))
        tenant_a = k8s.user(f"tenant-a-{suffix}", groups=(tenants,))
        # What the platform team does with `edit` (aggregation needs the controller-manager).
        k8s.kubectl("create", "rolebinding", "tenant-edit", "-n", team_a,
                    f"--clusterrole={fullname}-tenant-edit", f"--user={tenant_a.name}")
        # The built-in edit role is an aggregation; its rules (pods, exec, secrets, and read
        # rights from view) are in the roles the apiserver bootstraps: bind those, like edit.
        editor = k8s.user(f"editor-{suffix}", groups=(tenants,))
        for role in ("system:aggregate-to-edit", "system:aggregate-to-view", f"{fullname}-tenant-edit"):
            k8s.kubectl("create", "rolebinding", f"editor-{role.replace(':', '-')}", "-n", team_a,
                        f"--clusterrole={role}", f"--user={editor.name}")
        tokens = tmp_path_factory.mktemp("helm-rbac")
        yield Release(
            plane=k8s, fullname=fullname, namespace=namespace, team_a=team_a, team_b=team_b,
            operator=token_kubeconfig(k8s, f"{fullname}-operator", namespace, tokens / "operator"),
            agent=token_kubeconfig(k8s, f"{fullname}-agent", namespace, tokens / "agent"),
            tenant_a=tenant_a, editor=editor,
        )
    finally:
        k8s.kubectl("delete", "--ignore-not-found", "--wait=false", *cluster_objects, check=False)
        for ns in (namespace, team_a, team_b):
            k8s.delete_namespace(ns)


# ---------------------------------------------------------------------------- operator
def test_operator_account_cannot_read_secrets(release: Release) -> None:
    assert forbidden(release.as_(release.operator, "get", "secret", JOB_SECRET, "-n", release.team_a))
    assert forbidden(release.as_(release.operator, "get", "secrets", "-n", release.namespace))
    assert not release.can(release.operator, "list", "secrets")


def test_operator_account_cannot_read_pods(release: Release) -> None:
    assert forbidden(release.as_(release.operator, "get", "pods", "-n", release.team_a))
    assert not release.can(release.operator, "get", "pods")


def test_operator_account_writes_jobs_cells_their_status_and_only_its_lease(release: Release) -> None:
    assert release.as_(release.operator, "get", "robotjobs", "-A").returncode == 0
    assert release.can(release.operator, "patch", "robotjobs", subresource="status")
    assert release.can(release.operator, "patch", "cells", subresource="status")
    assert release.can(release.operator, "watch", "cellquotas")
    assert release.can(release.operator, "patch", "cellquotas", subresource="status")
    assert release.can(release.operator, "delete", "robotjobs")
    assert release.can(release.operator, "create", "events")
    assert release.can(release.operator, "create", "leases", release.namespace)
    assert release.can(release.operator, "patch", f"leases/{release.fullname}-operator", release.namespace)
    assert not release.can(release.operator, "patch", "leases/kube-scheduler", release.namespace)
    assert not release.can(release.operator, "create", "leases", release.team_a)


def test_operator_account_cannot_change_cell_specs(release: Release) -> None:
    assert not release.can(release.operator, "patch", "cells")
    assert not release.can(release.operator, "create", "cells")
    assert not release.can(release.operator, "patch", "cellquotas")  # tenants' shares are the admin's


# ---------------------------------------------------------------------------- agent
def test_agent_account_reads_a_secret_a_job_references(release: Release) -> None:
    result = release.as_(release.agent, "get", "secret", JOB_SECRET, "-n", release.team_a, "-o", "json")

    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["metadata"]["name"] == JOB_SECRET


def test_agent_account_reads_only_the_listed_model_configmaps_and_only_in_the_release_namespace(
        release: Release) -> None:
    assert release.can(release.agent, "get", f"configmaps/{MODEL_CONFIGMAP}", release.namespace)
    assert not release.can(release.agent, "get", "configmaps/kube-root-ca.crt", release.namespace)
    assert not release.can(release.agent, "list", "configmaps", release.namespace)
    assert not release.can(release.agent, "get", f"configmaps/{MODEL_CONFIGMAP}", release.team_a)


def test_agent_account_cannot_read_another_secret(release: Release) -> None:
    assert forbidden(release.as_(release.agent, "get", "secret", OTHER_SECRET, "-n", release.team_a))


def test_agent_account_cannot_list_secrets_of_a_job_namespace(release: Release) -> None:
    # A list would return every Secret of the namespace, whatever resourceNames say.
    assert forbidden(release.as_(release.agent, "get", "secrets", "-n", release.team_a))


def test_agent_account_cannot_read_a_listed_name_in_another_namespace(release: Release) -> None:
    assert forbidden(release.as_(release.agent, "get", "secret", JOB_SECRET, "-n", release.team_b))


def test_agent_account_manages_pods_only_in_job_namespaces(release: Release) -> None:
    for ns in (release.team_a, release.team_b):
        assert release.can(release.agent, "create", "pods", ns)
        assert release.can(release.agent, "delete", "pods", ns)
        assert release.can(release.agent, "patch", "pods", ns)  # stopping a job lowers its pod's deadline
        assert release.can(release.agent, "get", "pods", ns, subresource="log")
    assert not release.can(release.agent, "create", "pods", release.namespace)
    assert not release.can(release.agent, "create", "pods", "kube-system")


def test_agent_account_writes_status_but_not_specs(release: Release) -> None:
    assert release.can(release.agent, "patch", "cells", subresource="status")
    assert release.can(release.agent, "patch", "robotjobs", subresource="status")
    assert release.as_(release.agent, "get", "cells").returncode == 0
    assert not release.can(release.agent, "patch", "robotjobs")
    assert not release.can(release.agent, "patch", "cells")


def pod(name: str, node: str, **spec: Any) -> str:
    return json.dumps({"apiVersion": "v1", "kind": "Pod", "metadata": {"name": name}, "spec": {
        "nodeName": node, "containers": [{"name": "main", "image": "localhost/job:dev"}], **spec}})


def test_agent_creates_stops_and_deletes_pods_only_on_the_node_it_runs_on(release: Release, tmp_path: Path) -> None:
    node = f"robot-host-{uuid.uuid4().hex[:6]}"
    plane = release.plane
    plane.kubectl("create", "-f", "-", input=json.dumps({"apiVersion": "v1", "kind": "Node",
                                                         "metadata": {"name": node}}))
    try:
        # The agent's own pod as its DaemonSet would place it; its token names the node.
        plane.kubectl("create", "-n", release.namespace, "-f", "-", input=pod(
            "agent", node, serviceAccountName=f"{release.fullname}-agent"))
        agent = token_kubeconfig(plane, f"{release.fullname}-agent", release.namespace,
                                 tmp_path / "agent-on-node", bound_pod="agent")
        # The API server loads a new policy from its informer (about a second): wait for it
        # with dry runs (admission runs, nothing is stored), then try for real.
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and release.as_(
                agent, "create", "--dry-run=server", "-n", release.team_a, "-f", "-",
                input=pod("probe", "another-host")).returncode == 0:
            time.sleep(0.3)
        elsewhere = release.as_(agent, "create", "-n", release.team_a, "-f", "-",
                                input=pod("job-elsewhere", "another-host"))
        here = release.as_(agent, "create", "-n", release.team_a, "-f", "-", input=pod("job-here", node))
        # Another host's job pod (made here by the admin): the agent may neither stop nor delete it.
        plane.kubectl("create", "-n", release.team_a, "-f", "-", input=pod("job-there", "another-host"))
        stop = '{"spec": {"activeDeadlineSeconds": 1}}'
        stop_there = release.as_(agent, "patch", "pod", "job-there", "-n", release.team_a, "-p", stop)
        delete_there = release.as_(agent, "delete", "pod", "job-there", "-n", release.team_a, "--wait=false")
        stop_here = release.as_(agent, "patch", "pod", "job-here", "-n", release.team_a, "-p", stop)
        delete_here = release.as_(agent, "delete", "pod", "job-here", "-n", release.team_a, "--wait=false")

        assert elsewhere.returncode != 0
        assert "only on the node it runs on" in elsewhere.stderr, elsewhere.stderr
        assert here.returncode == 0, here.stderr
        assert stop_there.returncode != 0 and "only on the node it runs on" in stop_there.stderr, stop_there.stderr
        assert delete_there.returncode != 0 and "only on the node it runs on" in delete_there.stderr, \
            delete_there.stderr
        assert stop_here.returncode == 0, stop_here.stderr
        assert delete_here.returncode == 0, delete_here.stderr
    finally:
        plane.kubectl("delete", "node", node, "--wait=false", check=False)


@pytest.mark.parametrize("account", ["operator", "agent"])
def test_neither_account_can_widen_its_own_rights(release: Release, account: str) -> None:
    who = getattr(release, account)
    for resource in ("roles", "rolebindings", "clusterroles", "clusterrolebindings"):
        assert not release.can(who, "create", f"{resource}.rbac.authorization.k8s.io", release.team_a)
        assert not release.can(who, "patch", f"{resource}.rbac.authorization.k8s.io", release.team_a)


# ---------------------------------------------------------------------------- tenants
def test_tenant_creates_and_cancels_a_robotjob_in_its_namespace(release: Release) -> None:
    created = release.as_(release.tenant_a, "create", "-n", release.team_a, "-f", "-", input=robotjob("mine"))
    cancelled = release.as_(release.tenant_a, "patch", "robotjob", "mine", "-n", release.team_a,
                            "--type=merge", "-p", '{"spec":{"cancel":true}}')

    assert created.returncode == 0, created.stderr
    assert cancelled.returncode == 0, cancelled.stderr


def test_tenant_cannot_create_a_robotjob_in_another_namespace(release: Release) -> None:
    result = release.as_(release.tenant_a, "create", "-n", release.team_b, "-f", "-", input=robotjob("theirs"))

    assert forbidden(result), result.stderr


def test_tenant_cannot_read_another_namespaces_jobs_or_results(release: Release) -> None:
    release.plane.kubectl("apply", "-n", release.team_b, "-f", "-", input=robotjob("b-job"))

    assert forbidden(release.as_(release.tenant_a, "get", "robotjob", "b-job", "-n", release.team_b))
    assert forbidden(release.as_(release.tenant_a, "get", "robotjobs", "-n", release.team_b))
    assert forbidden(release.as_(release.tenant_a, "get", "robotjobs", "-A"))
    assert forbidden(release.as_(release.tenant_a, "get", "robotjob", "b-job", "-n", release.team_b,
                                 "--subresource=status"))


def test_tenant_cannot_patch_a_robotjobs_status(release: Release) -> None:
    release.plane.kubectl("apply", "-n", release.team_a, "-f", "-", input=robotjob("forged"))

    result = release.as_(release.tenant_a, "patch", "robotjob", "forged", "-n", release.team_a,
                         "--subresource=status", "--type=merge",
                         "-p", '{"status":{"phase":"succeeded","result":{"success":true}}}')

    assert forbidden(result), result.stderr
    stored = json.loads(release.plane.kubectl("get", "robotjob", "forged", "-n", release.team_a,
                                              "-o", "json").stdout)
    assert stored.get("status", {}).get("phase") != "succeeded"


@pytest.mark.parametrize("resource", ["cells", "cellquotas"])
def test_tenant_reads_cells_and_quotas_but_cannot_edit_them(release: Release, resource: str) -> None:
    assert release.as_(release.tenant_a, "get", resource).returncode == 0
    for verb in ("create", "patch", "update", "delete"):
        assert not release.can(release.tenant_a, verb, resource)
    assert not release.can(release.tenant_a, "patch", resource, subresource="status")


def test_the_chart_tenant_role_grants_no_pods_so_no_way_into_a_job_pod(release: Release) -> None:
    # docs/helm.md binds tenants this role (not edit) in job namespaces: the admission
    # policy aside, they cannot make, change or enter the pods that hold the devices.
    for verb in ("create", "patch", "update"):
        assert not release.can(release.tenant_a, verb, "pods", release.team_a)
    for subresource in ("exec", "attach", "portforward", "proxy"):
        assert not release.can(release.tenant_a, "create", "pods", release.team_a, subresource=subresource)
    assert not release.can(release.tenant_a, "get", "pods", release.team_a, subresource="proxy")


def test_tenant_cannot_read_secrets_through_the_chart_roles(release: Release) -> None:
    assert forbidden(release.as_(release.tenant_a, "get", "secret", JOB_SECRET, "-n", release.team_a))


# ---------------------------------------------------------------------------- job pods
# The job-pod policy (templates/job-pod-policy.yaml): job pods hold the robot's devices, so
# a user with `edit` in a job namespace can neither ask the kubelet for a cell's device nor
# make, change or enter a job pod; the agent still creates the pod its launcher builds.
CELL_RESOURCE = f"{CELL_RESOURCE_PREFIX}x"


@dataclass(frozen=True)
class RobotHost:
    node: str
    agent: Path  # the agent's token bound to its pod on ``node`` (the node-bound policy is on)


def job_pod(node: str, uid: str, namespace: str, *, device_resource: str | None = CELL_RESOURCE) -> dict[str, Any]:
    """The pod the agent's pod launcher builds for a job (the real builder, launch.pod_spec)."""
    labels = {LABEL_MANAGED_BY: MANAGED_BY_AGENT, LABEL_CELL: "x", LABEL_JOB_UID: uid,
              LABEL_NAMESPACE: namespace, LABEL_NAME: "job"}
    return build_pod(PodInputs(
        name=container_name(uid), namespace=namespace, node_name=node, job_name="job", job_uid=uid,
        labels=labels, job_image="localhost/job:dev", job_env={}, connector_image="localhost/armnet-agent:dev",
        connector_command=("armnet", "sidecar"), sidecar={}, socket_dir="/run/armnet",
        calibration_dir="/run/armnet-calibration", cache_dir="/var/lib/armnet/cache/x",
        volume_dir="/var/lib/armnet/volumes/ns", timeout_seconds=60, grace_seconds=5.0,
        device_resource=device_resource, observer_dir="/run/armnet-observer"))


def plain_pod(name: str, *, labels: dict[str, str] | None = None, resources: dict[str, Any] | None = None) -> str:
    container: dict[str, Any] = {"name": "main", "image": "localhost/job:dev"}
    if resources is not None:
        container["resources"] = resources
    return json.dumps({"apiVersion": "v1", "kind": "Pod", "metadata": {"name": name, "labels": labels or {}},
                       "spec": {"containers": [container]}})


@pytest.fixture(scope="module")
def job_pod_policy(release: Release) -> Release:
    """The release once the API server enforces the job-pod policy (its informer loads a new
    policy in about a second): dry runs run admission and store nothing."""
    probe = plain_pod("probe", resources={"limits": {CELL_RESOURCE: "1"}})
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and release.as_(
            release.editor, "create", "--dry-run=server", "-n", release.team_a, "-f", "-", input=probe).returncode == 0:
        time.sleep(0.3)
    return release


@pytest.fixture(scope="module")
def robot_host(job_pod_policy: Release, tmp_path_factory: pytest.TempPathFactory) -> Iterator[RobotHost]:
    release = job_pod_policy
    node = f"robot-host-{uuid.uuid4().hex[:6]}"
    release.plane.kubectl("create", "-f", "-", input=json.dumps({"apiVersion": "v1", "kind": "Node",
                                                                 "metadata": {"name": node}}))
    try:
        release.plane.kubectl("create", "-n", release.namespace, "-f", "-", input=pod(
            f"agent-{node}", node, serviceAccountName=f"{release.fullname}-agent"))
        yield RobotHost(node, token_kubeconfig(release.plane, f"{release.fullname}-agent", release.namespace,
                                               tmp_path_factory.mktemp("robot-host") / "agent",
                                               bound_pod=f"agent-{node}"))
    finally:
        release.plane.kubectl("delete", "node", node, "--wait=false", check=False)


@pytest.fixture()
def running_job_pod(job_pod_policy: Release, robot_host: RobotHost) -> str:
    """A job pod as the agent creates it (by the agent's own account); its name."""
    manifest = job_pod(robot_host.node, str(uuid.uuid4()), job_pod_policy.team_a)
    created = job_pod_policy.as_(robot_host.agent, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                 input=json.dumps(manifest))
    assert created.returncode == 0, created.stderr
    return str(manifest["metadata"]["name"])


def test_an_editor_cannot_create_a_pod_requesting_a_cell_device(job_pod_policy: Release) -> None:
    result = job_pod_policy.as_(job_pod_policy.editor, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                input=plain_pod("grab", resources={"limits": {CELL_RESOURCE: "1"}}))

    assert forbidden(result), result.stderr
    assert "only the armnet agent may request armnet.io/cell-* resources" in result.stderr


def test_an_editor_cannot_create_a_pod_with_the_job_pod_labels(job_pod_policy: Release) -> None:
    result = job_pod_policy.as_(job_pod_policy.editor, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                input=plain_pod("fake", labels={MANAGED_BY_LABEL: "armnet-agent"}))

    assert forbidden(result), result.stderr
    assert "only the armnet agent may create armnet job pods" in result.stderr


def test_an_editor_cannot_precreate_the_pod_the_agent_would_adopt(job_pod_policy: Release) -> None:
    name = f"armnet-{uuid.uuid4()}"

    result = job_pod_policy.as_(job_pod_policy.editor, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                input=plain_pod(name))

    assert forbidden(result), result.stderr


def test_an_editor_still_creates_an_ordinary_pod(job_pod_policy: Release) -> None:
    result = job_pod_policy.as_(job_pod_policy.editor, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                input=plain_pod(f"ordinary-{uuid.uuid4().hex[:6]}"))

    assert result.returncode == 0, result.stderr


def test_an_editor_still_creates_a_pod_with_a_generated_name(job_pod_policy: Release) -> None:
    # A Deployment's pods are named by generateName: the policy must not trip on a missing name.
    manifest = json.loads(plain_pod("unused"))
    manifest["metadata"] = {"generateName": "worker-"}

    result = job_pod_policy.as_(job_pod_policy.editor, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                input=json.dumps(manifest))

    assert result.returncode == 0, result.stderr


def test_the_agent_creates_and_stops_the_job_pod_its_launcher_builds(job_pod_policy: Release,
                                                                       robot_host: RobotHost) -> None:
    manifest = job_pod(robot_host.node, str(uuid.uuid4()), job_pod_policy.team_a)
    name = manifest["metadata"]["name"]

    created = job_pod_policy.as_(robot_host.agent, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                 input=json.dumps(manifest))
    stopped = job_pod_policy.as_(robot_host.agent, "patch", "pod", name, "-n", job_pod_policy.team_a,
                                 "-p", '{"spec": {"activeDeadlineSeconds": 1}}')

    assert created.returncode == 0, created.stderr
    assert stopped.returncode == 0, stopped.stderr


def test_the_agent_cannot_give_a_cell_device_to_the_customer_container(job_pod_policy: Release,
                                                                        robot_host: RobotHost) -> None:
    manifest = job_pod(robot_host.node, str(uuid.uuid4()), job_pod_policy.team_a)
    manifest["spec"]["containers"][0]["resources"]["limits"][CELL_RESOURCE] = "1"

    result = job_pod_policy.as_(robot_host.agent, "create", "-n", job_pod_policy.team_a, "-f", "-",
                                input=json.dumps(manifest))

    assert forbidden(result), result.stderr
    assert "only for the init container named connector" in result.stderr


def test_an_editor_cannot_exec_into_a_job_pods_connector(job_pod_policy: Release, running_job_pod: str) -> None:
    # Admission refuses before the API server would dial the kubelet (this bed has none).
    result = job_pod_policy.as_(job_pod_policy.editor, "exec", running_job_pod, "-n", job_pod_policy.team_a,
                                "-c", "connector", "--", "true")

    assert forbidden(result), result.stderr
    assert "nobody may exec, attach, port-forward or proxy into an armnet job pod" in result.stderr


def test_an_editor_cannot_change_a_job_pods_connector_image(job_pod_policy: Release, running_job_pod: str) -> None:
    patch = json.dumps({"spec": {"initContainers": [{"name": "connector", "image": "evil/connector:1"}]}})

    result = job_pod_policy.as_(job_pod_policy.editor, "patch", "pod", running_job_pod, "-n", job_pod_policy.team_a,
                                "-p", patch)

    assert forbidden(result), result.stderr
    assert "only the armnet agent may change an armnet job pod" in result.stderr


def test_an_editor_cannot_relabel_a_job_pod(job_pod_policy: Release, running_job_pod: str) -> None:
    result = job_pod_policy.as_(job_pod_policy.editor, "label", "pod", running_job_pod, "-n", job_pod_policy.team_a,
                                f"{MANAGED_BY_LABEL}-")

    assert forbidden(result), result.stderr


def test_the_garbage_collectors_owner_reference_edit_of_a_job_pod_passes(job_pod_policy: Release,
                                                                         running_job_pod: str) -> None:
    # Orphaning (deleting the RobotJob with --cascade=orphan) removes only the owner reference.
    result = job_pod_policy.plane.kubectl("patch", "pod", running_job_pod, "-n", job_pod_policy.team_a,
                                          "--type=json", "-p", '[{"op": "remove", "path": "/metadata/ownerReferences"}]',
                                          check=False)

    assert result.returncode == 0, result.stderr


def test_an_editor_may_delete_its_job_pod(job_pod_policy: Release, running_job_pod: str) -> None:
    result = job_pod_policy.as_(job_pod_policy.editor, "delete", "pod", running_job_pod, "-n", job_pod_policy.team_a,
                                "--wait=false")

    assert result.returncode == 0, result.stderr



def test_an_editor_cannot_proxy_to_a_job_pods_port(job_pod_policy: Release, running_job_pod: str) -> None:
    path = f"/api/v1/namespaces/{job_pod_policy.team_a}/pods/{running_job_pod}:8080/proxy/"

    result = job_pod_policy.as_(job_pod_policy.editor, "get", "--raw", path)

    assert forbidden(result), result.stderr
    assert "nobody may exec, attach, port-forward or proxy into an armnet job pod" in result.stderr


def test_nobody_adds_a_debug_container_beside_a_job_pods_connector(job_pod_policy: Release,
                                                                     running_job_pod: str) -> None:
    # Even the cluster admin: an ephemeral container targeting the connector shares its processes.
    result = job_pod_policy.plane.kubectl("debug", running_job_pod, "-n", job_pod_policy.team_a,
                                          "--image=localhost/job:dev", "--target=connector", "--", "true",
                                          check=False)

    assert result.returncode != 0
    assert "only the armnet agent may change an armnet job pod" in result.stderr, result.stderr
