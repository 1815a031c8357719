"""The armnet Helm chart renders what the platform team needs, and the API server accepts it.

Real `helm` (built by scripts/setup.d/35-helm.sh) and, for the dry-run, the test bed's
real kube-apiserver. RBAC behaviour with real identities: test_helm_rbac.py.
"""

from __future__ import annotations

import re
from typing import Any

import pytest
import yaml
from armnet_core.api import GROUP, RELEASE_CELL_FINALIZER, ROBOTJOBS
from armnet_testbed.kube import ControlPlane

from tests.support.helm import ALL_OPTIONS, CHART, REPO_ROOT, env_of, find, helm, notes, render

pytestmark = pytest.mark.integration


# ---------------------------------------------------------------------------- helpers
def repo_crds() -> dict[str, dict[str, Any]]:
    return {doc["metadata"]["name"]: doc for path in sorted((REPO_ROOT / "crds").glob("*.yaml"))
            for doc in yaml.safe_load_all(path.read_text()) if doc}


# ---------------------------------------------------------------------------- CRDs
def test_chart_crd_files_are_byte_identical_to_the_repository_crds() -> None:
    source = {p.name: p.read_bytes() for p in (REPO_ROOT / "crds").glob("*.yaml")}
    chart = {p.name: p.read_bytes() for p in (CHART / "files" / "crds").glob("*.yaml")}

    stale = sorted(n for n in source.keys() | chart.keys() if source.get(n) != chart.get(n))
    assert not stale, (f"helm/armnet/files/crds differs from crds/ in {stale}: crds/ is the single "
                       "source; run `cp crds/*.yaml helm/armnet/files/crds/`")


def test_rendered_crds_are_the_repository_crds_kept_on_uninstall() -> None:
    rendered = {o["metadata"]["name"]: o for o in render() if o["kind"] == "CustomResourceDefinition"}

    assert rendered.keys() == repo_crds().keys()
    for name, crd in repo_crds().items():
        assert rendered[name]["spec"] == crd["spec"], f"{name}: rendering changed the schema"
        assert rendered[name]["metadata"]["annotations"]["helm.sh/resource-policy"] == "keep"


def test_crds_are_templates_so_upgrades_apply_them() -> None:
    # Helm installs a chart's crds/ folder only on first install and never upgrades it.
    assert not (CHART / "crds").exists()
    assert any(o["kind"] == "CustomResourceDefinition" for o in render())


def test_crds_can_be_left_to_another_release() -> None:
    assert not [o for o in render(values={"crds": {"install": False}}) if o["kind"] == "CustomResourceDefinition"]


# ---------------------------------------------------------------------------- lint and schema
def test_helm_lint_passes_strict_with_default_values() -> None:
    result = helm("lint", "--strict", str(CHART))

    assert "0 chart(s) failed" in result.stdout


def test_helm_lint_passes_strict_with_every_option_on() -> None:
    result = helm("lint", "--strict", str(CHART), "--values", str(ALL_OPTIONS))

    assert "0 chart(s) failed" in result.stdout


def test_every_option_on_renders_every_kind_the_chart_knows() -> None:
    kinds = {o["kind"] for o in render(values_files=[ALL_OPTIONS])}

    assert kinds == {"CustomResourceDefinition", "ServiceAccount", "ClusterRole", "ClusterRoleBinding",
                     "Role", "RoleBinding", "Deployment", "PodDisruptionBudget", "DaemonSet", "Service",
                     "ConfigMap", "StatefulSet", "ServiceMonitor", "PrometheusRule",
                     "ValidatingAdmissionPolicy", "ValidatingAdmissionPolicyBinding",
                     "Secret", "ValidatingWebhookConfiguration", "NetworkPolicy"}


@pytest.mark.parametrize(("values", "path"), [
    ({"operator": {"replicas": "two"}}, "operator.replicas"),
    ({"operator": {"metricsPort": "http"}}, "operator.metricsPort"),
    ({"operator": {"settings": {"heartbeatTimeout": "30s"}}}, "operator.settings.heartbeatTimeout"),
    ({"agent": {"enabled": "yes"}}, "agent.enabled"),
    ({"agent": {"robotHostLabel": "armnet.io/robot-host"}}, "agent.robotHostLabel"),
    ({"agent": {"args": "agent --node-name x"}}, "agent.args"),
    ({"agent": {"launcher": "podman"}}, "agent.launcher"),
    ({"jobNamespaces": ["team-a"]}, "jobNamespaces.0"),
    ({"jobNamespaces": [{"name": "Team_A"}]}, "jobNamespaces.0.name"),
    ({"nats": {"deploy": {"enabled": 1}}}, "nats.deploy.enabled"),
    ({"nats": {"url": "http://nats:4222"}}, "nats.url"),
    ({"metrics": {"serviceMonitor": {"interval": 30}}}, "metrics.serviceMonitor.interval"),
    ({"rbac": {"tenants": {"cellReaderGroups": "armnet:tenants"}}}, "rbac.tenants.cellReaderGroups"),
    ({"rbac": {"jobPodPolicy": "on"}}, "rbac.jobPodPolicy"),
    ({"operatr": {"replicas": 2}}, "operatr"),
])
def test_schema_rejects_wrong_types_and_unknown_keys(values: dict[str, Any], path: str) -> None:
    result = helm("template", "armnet", str(CHART), "--values", "-", input=yaml.safe_dump(values),
                  check=False)

    assert result.returncode != 0
    assert "values don't meet the specifications of the schema" in result.stderr, result.stderr
    assert "/" + path.replace(".", "/") in result.stderr or f"'{path.split('.')[-1]}'" in result.stderr, \
        result.stderr


def test_schema_requires_a_password_secret_when_nats_auth_is_on() -> None:
    values = {"nats": {"deploy": {"enabled": True, "auth": {"enabled": True}}}}
    result = helm("template", "armnet", str(CHART), "--values", "-", input=yaml.safe_dump(values),
                  check=False)

    assert result.returncode != 0 and "existingSecret" in result.stderr, result.stderr


# ---------------------------------------------------------------------------- names
@pytest.mark.parametrize(("release", "prefix"), [("robots", "robots-armnet"), ("armnet-prod", "armnet-prod")])
def test_a_release_name_other_than_armnet_prefixes_every_object(release: str, prefix: str) -> None:
    objects = [o for o in render(release, "ops", values_files=[ALL_OPTIONS])
               if o["kind"] != "CustomResourceDefinition"]

    assert all(o["metadata"]["name"].startswith(prefix) for o in objects), \
        [o["metadata"]["name"] for o in objects if not o["metadata"]["name"].startswith(prefix)]
    binding = find(objects, "ClusterRoleBinding", "-operator")
    assert binding["subjects"] == [{"kind": "ServiceAccount", "name": f"{prefix}-operator", "namespace": "ops"}]
    lease_env = env_of(find(objects, "Deployment", "-operator")["spec"]["template"]["spec"]["containers"][0])
    assert lease_env["ARMNET_OPERATOR_LEASE_NAMESPACE"] == "ops"


def test_namespaced_objects_name_their_namespace() -> None:
    objects = render("robots", "ops", values_files=[ALL_OPTIONS])
    cluster_kinds = {"CustomResourceDefinition", "ClusterRole", "ClusterRoleBinding",
                     "ValidatingAdmissionPolicy", "ValidatingAdmissionPolicyBinding", "ValidatingWebhookConfiguration"}

    for o in objects:
        if o["kind"] in cluster_kinds:
            assert "namespace" not in o["metadata"], o["metadata"]["name"]
        else:
            assert o["metadata"].get("namespace"), f"{o['kind']} {o['metadata']['name']} has no namespace"


# ---------------------------------------------------------------------------- operator
def test_operator_runs_two_replicas_with_the_lease_in_the_release_namespace() -> None:
    objects = render("robots", "ops")
    deployment = find(objects, "Deployment", "-operator")
    env = env_of(deployment["spec"]["template"]["spec"]["containers"][0])

    assert deployment["spec"]["replicas"] == 2
    assert env["ARMNET_OPERATOR_LEASE_NAME"] == "robots-armnet-operator"
    assert env["ARMNET_OPERATOR_LEASE_NAMESPACE"] == "ops"
    assert env["ARMNET_OPERATOR_LEASE_DURATION"] == "15"
    lease_role = find(objects, "Role", "-operator-lease")
    assert {"resourceNames": ["robots-armnet-operator"], "verbs": ["get", "update", "patch"],
            "apiGroups": ["coordination.k8s.io"], "resources": ["leases"]} in lease_role["rules"]


def test_operator_settings_reach_its_environment() -> None:
    values = {"operator": {"settings": {"heartbeatTimeout": 45, "defaultTtl": "none"}},
              "jobNamespaces": [{"name": "team-a"}, {"name": "team-b"}]}
    env = env_of(find(render(values=values), "Deployment")["spec"]["template"]["spec"]["containers"][0])

    assert env["ARMNET_OPERATOR_HEARTBEAT_TIMEOUT"] == "45"
    assert env["ARMNET_OPERATOR_DEFAULT_TTL"] == "none"
    assert env["ARMNET_OPERATOR_NAMESPACES"] == "team-a,team-b"


def test_operator_probes_its_metrics_port_and_has_a_disruption_budget() -> None:
    objects = render()
    container = find(objects, "Deployment")["spec"]["template"]["spec"]["containers"][0]
    pdb = find(objects, "PodDisruptionBudget")

    assert container["ports"][0] == {"name": "metrics", "containerPort": 8080, "protocol": "TCP"}
    assert container["livenessProbe"]["httpGet"] == {"path": "/metrics", "port": "metrics"}
    assert container["readinessProbe"]["httpGet"] == {"path": "/metrics", "port": "metrics"}
    assert container["resources"]["requests"] and container["resources"]["limits"]
    assert pdb["spec"]["minAvailable"] == 1
    assert pdb["spec"]["selector"]["matchLabels"] == \
        find(objects, "Deployment")["spec"]["selector"]["matchLabels"]


def test_operator_runs_non_root_read_only_with_only_a_projected_token() -> None:
    pod = find(render(), "Deployment")["spec"]["template"]["spec"]
    container = pod["containers"][0]

    assert pod["securityContext"]["runAsNonRoot"] is True
    assert container["securityContext"]["readOnlyRootFilesystem"] is True
    assert container["securityContext"]["allowPrivilegeEscalation"] is False
    assert container["securityContext"]["capabilities"] == {"drop": ["ALL"]}
    assert pod["automountServiceAccountToken"] is False
    token = next(v for v in pod["volumes"] if v["name"] == "kube-api-access")
    assert token["projected"]["sources"][0]["serviceAccountToken"]["expirationSeconds"] <= 3607


FMS_ON = {"fms": {"enabled": True, "operators": [{"name": "maria", "token": "maria-token-0123456789abcdef"}]}}


def pod_security(objects: list[dict[str, Any]], suffix: str) -> dict[str, Any]:
    return dict(find(objects, "Deployment", suffix)["spec"]["template"]["spec"]["securityContext"])


def test_operator_and_fms_pods_run_as_the_images_user_by_default() -> None:
    objects = render(values=FMS_ON)

    for suffix in ("-operator", "-fms"):
        assert pod_security(objects, suffix) == {"runAsNonRoot": True, "runAsUser": 65532, "runAsGroup": 65532,
                                                 "seccompProfile": {"type": "RuntimeDefault"}}, suffix


def test_operator_and_fms_users_are_values_and_may_be_left_to_the_platform() -> None:
    mine = {"podSecurityContext": {"runAsUser": 1001, "runAsGroup": 1001}}
    assigned = {"podSecurityContext": {"runAsUser": None, "runAsGroup": None}}
    custom = render(values={"operator": mine, "fms": {**FMS_ON["fms"], **mine}})
    openshift = render(values={"operator": assigned, "fms": {**FMS_ON["fms"], **assigned}})

    for suffix in ("-operator", "-fms"):
        context = pod_security(custom, suffix)
        assert (context["runAsUser"], context["runAsGroup"], context["runAsNonRoot"]) == (1001, 1001, True)
        context = pod_security(openshift, suffix)
        assert "runAsUser" not in context and "runAsGroup" not in context and context["runAsNonRoot"] is True
        container = find(openshift, "Deployment", suffix)["spec"]["template"]["spec"]["containers"][0]
        assert container["securityContext"]["runAsNonRoot"] is True, "the container stays non-root either way"


@pytest.mark.parametrize("values", [
    {"operator": {"podSecurityContext": {"runAsNonRoot": True, "runAsUser": 0}}},
    {"operator": {"podSecurityContext": {"runAsNonRoot": False}}},
    {"fms": {"podSecurityContext": {"runAsNonRoot": True, "runAsUser": "nobody"}}},
])
def test_schema_refuses_a_root_or_non_numeric_operator_or_fms_user(values: dict[str, Any]) -> None:
    result = helm("template", "armnet", str(CHART), "--values", "-", input=yaml.safe_dump(values), check=False)

    assert result.returncode != 0
    assert "podSecurityContext" in result.stderr, result.stderr


# ---------------------------------------------------------------------------- NOTES and README
def test_notes_say_what_was_installed_and_how_to_label_a_host_register_a_cell_and_submit_a_job(
    k8s: ControlPlane,
) -> None:
    values = {"agent": {"robotHostLabel": {"key": "example.com/robot", "value": "so101"}},
              "jobNamespaces": [{"name": "team-x"}], "nats": {"url": "nats://nats.example:4222"}}
    text = notes(k8s, "robots", "ops", values=values)

    assert 'release "robots" in namespace ops' in text
    assert "Deployment robots-armnet-operator, 2 replica(s)" in text
    assert "DaemonSet robots-armnet-agent, on nodes labelled example.com/robot=so101" in text
    assert "kubectl label node <robot-host> example.com/robot=so101" in text
    assert "kind: Cell" in text and "kind: RobotJob" in text
    assert "kubectl apply -n team-x -f - <<EOF" in text
    assert "--clusterrole=robots-armnet-tenant-edit" in text
    assert "No NATS configured" not in text
    assert "cell operator's page" not in text, "the FMS is off by default"


def test_notes_warn_when_no_nats_is_configured_and_point_at_the_fms_when_it_is_on(k8s: ControlPlane) -> None:
    text = notes(k8s, values=FMS_ON)

    assert "No NATS configured" in text and "StreamsConnected=False" in text
    assert "kubectl -n armnet-system port-forward svc/armnet-fms 8080" in text


def test_the_chart_readme_is_what_helm_show_readme_prints_and_names_only_real_values() -> None:
    readme = helm("show", "readme", str(CHART)).stdout
    values = yaml.safe_load((CHART / "values.yaml").read_text())

    assert readme.startswith("# armnet")
    assert "helm uninstall" in readme and RELEASE_CELL_FINALIZER in readme
    named = set(re.findall(r"`((?:operator|agent|fms|nats|rbac|crds|metrics|admissionWebhook)\.[A-Za-z.]+)`", readme))
    assert {"operator.podSecurityContext", "fms.podSecurityContext", "agent.connectorImage"} <= named
    for path in named:
        node: Any = values
        for key in path.split("."):
            assert isinstance(node, dict) and key in node, f"README names {path}, which values.yaml does not have"
            node = node[key]


# ---------------------------------------------------------------------------- agent
def test_operator_and_agent_run_their_own_images_at_the_chart_version() -> None:
    objects = render()
    operator = find(objects, "Deployment")["spec"]["template"]["spec"]["containers"][0]
    agent = find(objects, "DaemonSet")["spec"]["template"]["spec"]["containers"][0]

    assert operator["image"] == "localhost/armnet-operator:0.1.0"
    assert agent["image"] == "localhost/armnet-agent:0.1.0"
    assert env_of(agent)["ARMNET_AGENT_CONNECTOR_IMAGE"] == "localhost/armnet-agent:0.1.0"


def test_one_tag_moves_both_images() -> None:
    objects = render(values={"image": {"tag": "abc123"}})
    images = [c["image"] for kind in ("Deployment", "DaemonSet")
              for c in find(objects, kind)["spec"]["template"]["spec"]["containers"]]

    assert images == ["localhost/armnet-operator:abc123", "localhost/armnet-agent:abc123"]


def test_pods_use_the_pod_network_unless_host_network_is_asked_for() -> None:
    default = render()
    on = render(values={"operator": {"hostNetwork": True}, "agent": {"hostNetwork": True}})

    for kind in ("Deployment", "DaemonSet"):
        assert "hostNetwork" not in find(default, kind)["spec"]["template"]["spec"]
        pod = find(on, kind)["spec"]["template"]["spec"]
        assert (pod["hostNetwork"], pod["dnsPolicy"]) == (True, "ClusterFirstWithHostNet")


def test_agent_runs_only_on_nodes_with_the_configured_robot_host_label() -> None:
    values = {"agent": {"robotHostLabel": {"key": "example.com/robot", "value": "so101"}}}
    pod = find(render(values=values), "DaemonSet")["spec"]["template"]["spec"]

    assert pod["nodeSelector"] == {"example.com/robot": "so101"}


def test_agent_runs_jobs_as_pods_with_the_simulator_in_their_sidecar_by_default() -> None:
    env = env_of(find(render(), "DaemonSet")["spec"]["template"]["spec"]["containers"][0])

    assert (env["ARMNET_AGENT_LAUNCHER"], env["ARMNET_AGENT_POD_SIMULATOR"]) == ("pod", "sidecar")
    assert env["ARMNET_AGENT_IMAGE_PULL_POLICY"] == "IfNotPresent"


def test_agent_may_run_jobs_through_a_container_engine_instead() -> None:
    env = env_of(find(render(values={"agent": {"launcher": "container"}}), "DaemonSet")
                 ["spec"]["template"]["spec"]["containers"][0])

    assert env["ARMNET_AGENT_LAUNCHER"] == "container"


def test_agent_holds_no_capability_but_chown_for_the_job_pods_host_dirs() -> None:
    container = find(render(), "DaemonSet")["spec"]["template"]["spec"]["containers"][0]

    assert container["securityContext"]["capabilities"] == {"drop": ["ALL"], "add": ["CHOWN"]}
    assert container["securityContext"]["privileged"] is False


def test_agent_gets_its_node_name_from_the_downward_api() -> None:
    container = find(render(), "DaemonSet")["spec"]["template"]["spec"]["containers"][0]

    assert container["args"] == ["agent", "--node-name", "$(NODE_NAME)"]
    assert env_of(container)["NODE_NAME"] == {"fieldRef": {"fieldPath": "spec.nodeName"}}


def test_agent_mounts_calibration_cache_and_the_device_plugin_dir() -> None:
    pod = find(render(), "DaemonSet")["spec"]["template"]["spec"]
    host_paths = {v["name"]: v["hostPath"]["path"] for v in pod["volumes"] if "hostPath" in v}
    mounts = {m["name"]: m for m in pod["containers"][0]["volumeMounts"]}

    assert host_paths == {"calibration": "/var/lib/armnet/calibration", "cache": "/var/lib/armnet/cache",
                          "device-plugins": "/var/lib/kubelet/device-plugins",
                          "kubelet-pods": "/var/lib/kubelet/pods",
                          "completion-files-0": "/var/lib/armnet/models",
                          "completion-files-1": "/var/lib/armnet/secrets"}
    assert mounts["device-plugins"]["mountPath"] == "/var/lib/kubelet/device-plugins"
    assert mounts["calibration"]["readOnly"] is True
    assert not pod["containers"][0]["securityContext"].get("privileged")


def test_agent_reads_completion_files_only_from_its_directories_mounted_read_only_at_the_same_path() -> None:
    dirs = ["/srv/armnet/models"]
    pod = find(render(values={"agent": {"completionFiles": {"hostPaths": dirs}}}), "DaemonSet")["spec"]["template"]["spec"]
    container = pod["containers"][0]
    mounts = {m["name"]: m for m in container["volumeMounts"]}
    volumes = {v["name"]: v for v in pod["volumes"]}

    assert volumes["completion-files-0"]["hostPath"] == {"path": "/srv/armnet/models", "type": "DirectoryOrCreate"}
    assert mounts["completion-files-0"] == {"name": "completion-files-0", "mountPath": "/srv/armnet/models",
                                            "readOnly": True}
    assert "completion-files-1" not in volumes
    assert env_of(container)["ARMNET_AGENT_COMPLETION_FILES_DIRS"] == "/srv/armnet/models"


def test_agent_reads_job_pods_observer_sockets_through_a_read_only_propagated_kubelet_pods_mount() -> None:
    pod = find(render(values={"agent": {"kubeletRootDir": "/srv/kubelet"}}), "DaemonSet")["spec"]["template"]["spec"]
    host_paths = {v["name"]: v["hostPath"] for v in pod["volumes"] if "hostPath" in v}
    container = pod["containers"][0]
    mount = {m["name"]: m for m in container["volumeMounts"]}["kubelet-pods"]

    assert host_paths["kubelet-pods"] == {"path": "/srv/kubelet/pods", "type": "Directory"}
    assert mount == {"name": "kubelet-pods", "mountPath": "/srv/kubelet/pods", "readOnly": True,
                     "mountPropagation": "HostToContainer"}
    assert env_of(container)["ARMNET_AGENT_KUBELET_ROOT_DIR"] == "/srv/kubelet"


def test_with_the_container_launcher_the_agent_does_not_mount_the_kubelets_pods() -> None:
    """That directory holds every pod's volumes (tokens, Secrets): mounted only when the pod launcher needs it."""
    pod = find(render(values={"agent": {"launcher": "container"}}), "DaemonSet")["spec"]["template"]["spec"]
    assert "kubelet-pods" not in {v["name"] for v in pod["volumes"]}
    assert "kubelet-pods" not in {m["name"] for m in pod["containers"][0]["volumeMounts"]}


def test_agent_nats_url_comes_from_a_value_or_a_secret() -> None:
    from_value = env_of(find(render(values={"nats": {"url": "nats://nats.example:4222"}}),
                             "DaemonSet")["spec"]["template"]["spec"]["containers"][0])
    from_secret = env_of(find(render(values={"nats": {"existingSecret": {"name": "nats-creds"}}}),
                              "DaemonSet")["spec"]["template"]["spec"]["containers"][0])

    assert from_value["ARMNET_AGENT_NATS_URL"] == "nats://nats.example:4222"
    assert from_secret["ARMNET_AGENT_NATS_URL"] == {"secretKeyRef": {"name": "nats-creds", "key": "url"}}


@pytest.mark.parametrize("kind", ["DaemonSet", "Deployment"])
def test_agent_and_operator_reach_the_outputs_bucket_with_keys_from_a_secret(kind: str) -> None:
    """The agent stores job outputs there; the operator removes a job's with the job at its TTL."""
    values = {"artifacts": {"bucket": "robot-outputs", "endpoint": "http://s3.storage:8333",
                            "credentialsSecret": "outputs-writer"}}
    env = env_of(find(render(values=values), kind)["spec"]["template"]["spec"]["containers"][0])
    without = env_of(find(render(), kind)["spec"]["template"]["spec"]["containers"][0])

    assert (env["ARMNET_ARTIFACTS_BUCKET"], env["ARMNET_ARTIFACTS_ENDPOINT"]) == ("robot-outputs", "http://s3.storage:8333")
    assert env["ARMNET_ARTIFACTS_SECRET_ACCESS_KEY"] == {
        "secretKeyRef": {"name": "outputs-writer", "key": "secretAccessKey"}}
    assert not [name for name in without if name.startswith("ARMNET_ARTIFACTS_")]
    # The operator's own keys (list and delete), when given: the robot hosts' keys need only write.
    values["artifacts"]["operatorCredentialsSecret"] = "outputs-remover"
    env = env_of(find(render(values=values), kind)["spec"]["template"]["spec"]["containers"][0])
    owner = "outputs-remover" if kind == "Deployment" else "outputs-writer"
    assert env["ARMNET_ARTIFACTS_ACCESS_KEY_ID"] == {"secretKeyRef": {"name": owner, "key": "accessKeyId"}}
    result = helm("template", "armnet", str(CHART), "--values", "-",
                  input=yaml.safe_dump({"artifacts": {"bucket": "robot-outputs"}}), check=False)
    assert result.returncode != 0 and "artifacts.credentialsSecret" in result.stderr, result.stderr


def test_agent_uses_the_bundled_nats_with_its_own_password() -> None:
    objects = render("robots", "ops", values_files=[ALL_OPTIONS])
    env = env_of(find(objects, "DaemonSet")["spec"]["template"]["spec"]["containers"][0])

    assert env["ARMNET_AGENT_NATS_URL"] == "nats://agent:$(NATS_AGENT_PASSWORD)@robots-armnet-nats.ops.svc:4222"
    assert env["NATS_AGENT_PASSWORD"] == {"secretKeyRef": {"name": "armnet-nats-users", "key": "agent"}}
    assert env["ARMNET_AGENT_CONNECTOR_IMAGE"] == "registry.example.com/armnet/connector:0.1.0"


# ---------------------------------------------------------------------------- RBAC shape
def rules_of(objects: list[dict[str, Any]], kind: str, suffix: str) -> list[dict[str, Any]]:
    return find(objects, kind, suffix)["rules"]


def test_operator_role_names_no_secrets_and_no_pods() -> None:
    rules = rules_of(render(), "ClusterRole", "-operator")
    resources = {r for rule in rules for r in rule["resources"]}

    assert not resources & {"secrets", "pods", "*"}
    assert not any("*" in rule["verbs"] for rule in rules)


def test_operator_reads_namespaces_only_when_it_serves_a_set_of_them() -> None:
    def reads_namespaces(objects: list[dict[str, Any]]) -> bool:
        return any("namespaces" in rule["resources"] and set(rule["verbs"]) == {"get", "list", "watch"}
                   for rule in rules_of(objects, "ClusterRole", "-operator"))

    assert reads_namespaces(render(values={"jobNamespaces": [{"name": "team-a"}]}))
    assert not reads_namespaces(render())


def test_agent_reads_only_the_listed_secrets_of_each_job_namespace() -> None:
    values = {"jobNamespaces": [{"name": "team-a", "secrets": ["hf-token"]}, {"name": "team-b"}]}
    objects = render(values=values)
    roles = {o["metadata"]["namespace"]: o for o in objects
             if o["kind"] == "Role" and o["metadata"]["name"].endswith("-agent")}
    cluster_resources = {r for rule in rules_of(objects, "ClusterRole", "-agent") for r in rule["resources"]}

    assert "secrets" not in cluster_resources and "pods" not in cluster_resources
    secret_rules = [r for r in roles["team-a"]["rules"] if "secrets" in r["resources"]]
    assert secret_rules == [{"apiGroups": [""], "resources": ["secrets"], "resourceNames": ["hf-token"],
                             "verbs": ["get"]}]
    assert not [r for r in roles["team-b"]["rules"] if "secrets" in r["resources"]]


def test_tenant_roles_aggregate_into_edit_admin_and_view() -> None:
    objects = render("robots", "ops")
    edit = find(objects, "ClusterRole", "-tenant-edit")
    view = find(objects, "ClusterRole", "-tenant-view")

    assert edit["metadata"]["labels"]["rbac.authorization.k8s.io/aggregate-to-edit"] == "true"
    assert edit["metadata"]["labels"]["rbac.authorization.k8s.io/aggregate-to-admin"] == "true"
    assert view["metadata"]["labels"]["rbac.authorization.k8s.io/aggregate-to-view"] == "true"
    assert edit["rules"] == [{"apiGroups": [GROUP], "resources": [ROBOTJOBS],
                              "verbs": ["create", "get", "list", "watch", "patch", "delete"]}]


def test_job_pod_policy_is_on_by_default_and_exempts_only_the_agent_account() -> None:
    policy = find(render("robots", "ops"), "ValidatingAdmissionPolicy", "-job-pods")
    is_agent = next(v for v in policy["spec"]["variables"] if v["name"] == "isAgent")

    assert is_agent["expression"] == "request.userInfo.username == 'system:serviceaccount:ops:robots-armnet-agent'"
    assert find(render("robots", "ops"), "ValidatingAdmissionPolicyBinding", "-job-pods")["spec"][
        "validationActions"] == ["Deny"]


def test_job_pod_policy_can_be_turned_off() -> None:
    objects = render("robots", "ops", values={"rbac": {"jobPodPolicy": False}})

    assert not [o for o in objects if o["metadata"]["name"].endswith("-job-pods")]


# ---------------------------------------------------------------------------- monitoring
OPERATOR_METRICS = REPO_ROOT / "operator" / "armnet_operator" / "metrics.py"
# The agent's metrics are defined in these two modules (docs/agent.md).
AGENT_METRICS = (REPO_ROOT / "agent" / "armnet_node" / "metrics.py", REPO_ROOT / "agent" / "armnet_node" / "stream_metrics.py")


def test_prometheus_rule_has_the_alerts_the_platform_team_watches() -> None:
    rule = find(render(values_files=[ALL_OPTIONS]), "PrometheusRule")
    alerts = {r["alert"]: r["expr"] for g in rule["spec"]["groups"] for r in g["rules"]}

    assert set(alerts) >= {"ArmnetCellOffline", "ArmnetInterlockTripped", "ArmnetJobStuckDispatched",
                           "ArmnetQueueWaitHigh", "ArmnetCellHeartbeatStale", "ArmnetAgentNatsDisconnected",
                           "ArmnetCellQuotaIgnored", "ArmnetJobOutputsNotUploaded"}


def test_prometheus_rule_uses_only_metrics_that_exist() -> None:
    rule = find(render(values_files=[ALL_OPTIONS]), "PrometheusRule")
    used = {m for g in rule["spec"]["groups"] for r in g["rules"]
            for m in re.findall(r"armnet_[a-z_]+", r["expr"])}
    operator_metrics = set(re.findall(r'"(armnet_[a-z_]+)"', OPERATOR_METRICS.read_text()))
    agent_metrics = {m for path in AGENT_METRICS for m in re.findall(r'"(armnet_[a-z_]+)"', path.read_text())}
    known = operator_metrics | {f"{m}_bucket" for m in operator_metrics} | agent_metrics

    assert {"armnet_agent_interlock_trips_total", "armnet_agent_job_outputs_pending"} <= agent_metrics

    assert used <= known, f"alerts use unknown metrics: {used - known}"


def test_service_monitors_scrape_the_metrics_services() -> None:
    objects = render(values_files=[ALL_OPTIONS])
    for component in ("operator", "agent"):
        monitor = find(objects, "ServiceMonitor", f"-{component}")
        service = find(objects, "Service", f"-{component}-metrics")
        assert monitor["spec"]["selector"]["matchLabels"].items() <= service["metadata"]["labels"].items()
        assert monitor["spec"]["endpoints"][0]["port"] == service["spec"]["ports"][0]["name"] == "metrics"


def test_no_monitoring_objects_unless_asked_for() -> None:
    kinds = {o["kind"] for o in render()}

    assert not kinds & {"ServiceMonitor", "PrometheusRule"}


# ---------------------------------------------------------------------------- the API server accepts it
# The Prometheus Operator's CRDs are not on the test bed. These two carry the fields
# of monitoring.coreos.com/v1 the chart uses, with the upstream types and required
# fields, so the API server checks our objects' structure (unknown fields are pruned
# and reported by kubectl's server-side field validation).
MONITORING_CRDS = """
apiVersion: apiextensions.k8s.io/v1
kind: CustomResourceDefinition
metadata: {name: servicemonitors.monitoring.coreos.com}
spec:
  group: monitoring.coreos.com
  scope: Namespaced
  names: {kind: ServiceMonitor, listKind: ServiceMonitorList, plural: servicemonitors, singular: servicemonitor}
  versions:
    - name: v1
      served: true
      storage: true
      schema:
        openAPIV3Schema:
          type: object
          required: [spec]
          properties:
            spec:
              type: object
              required: [selector]
              properties:
                selector:
                  type: object
                  properties:
                    matchLabels: {type: object, additionalProperties: {type: string}}
                namespaceSelector:
                  type: object
                  properties:
                    any: {type: boolean}
                    matchNames: {type: array, items: {type: string}}
                endpoints:
                  type: array
                  items:
                    type: object
                    properties:
                      port: {type: string}
                      path: {type: string}
                      interval: {type: string, pattern: '^(0|(([0-9]+)y)?(([0-9]+)w)?(([0-9]+)d)?(([0-9]+)h)?(([0-9]+)m)?(([0-9]+)s)?(([0-9]+)ms)?)$'}
---
apiVersion: apiextensions.k8s.io/v1
kind: CustomResourceDefinition
metadata: {name: prometheusrules.monitoring.coreos.com}
spec:
  group: monitoring.coreos.com
  scope: Namespaced
  names: {kind: PrometheusRule, listKind: PrometheusRuleList, plural: prometheusrules, singular: prometheusrule}
  versions:
    - name: v1
      served: true
      storage: true
      schema:
        openAPIV3Schema:
          type: object
          required: [spec]
          properties:
            spec:
              type: object
              properties:
                groups:
                  type: array
                  items:
                    type: object
                    required: [name]
                    properties:
                      name: {type: string, minLength: 1}
                      rules:
                        type: array
                        items:
                          type: object
                          required: [expr]
                          properties:
                            alert: {type: string}
                            record: {type: string}
                            expr: {x-kubernetes-int-or-string: true}
                            for: {type: string, pattern: '^(0|(([0-9]+)y)?(([0-9]+)w)?(([0-9]+)d)?(([0-9]+)h)?(([0-9]+)m)?(([0-9]+)s)?(([0-9]+)ms)?)$'}
                            labels: {type: object, additionalProperties: {type: string}}
                            annotations: {type: object, additionalProperties: {type: string}}
"""


@pytest.fixture(scope="module")
def monitoring_crds(k8s: ControlPlane) -> None:
    k8s.kubectl("apply", "--server-side", "-f", "-", input=MONITORING_CRDS)
    k8s.wait_established("crd/servicemonitors.monitoring.coreos.com", "crd/prometheusrules.monitoring.coreos.com")


def test_every_rendered_manifest_passes_a_server_side_dry_run(
        k8s: ControlPlane, namespace: str, monitoring_crds: None) -> None:
    team_a, team_b = k8s.create_namespace("helm-team-a"), k8s.create_namespace("helm-team-b")
    try:
        values = {"jobNamespaces": [{"name": team_a, "secrets": ["hf-token"]}, {"name": team_b}],
                  "nats": {"deploy": {"auth": {"tenants": [team_a, team_b]}}}}
        objects = render("dry-run", namespace, values_files=[ALL_OPTIONS], values=values)
        manifest = yaml.safe_dump_all(objects)

        result = k8s.kubectl("apply", "--dry-run=server", "--validate=strict", "-f", "-",
                             input=manifest, check=False)

        assert result.returncode == 0, result.stderr
        applied = [line for line in result.stdout.splitlines() if "(server dry run)" in line]
        assert len(applied) == len(objects), result.stdout
    finally:
        k8s.delete_namespace(team_a)
        k8s.delete_namespace(team_b)


def test_default_values_pass_a_server_side_dry_run(k8s: ControlPlane, namespace: str) -> None:
    manifest = yaml.safe_dump_all(render("defaults", namespace))

    result = k8s.kubectl("apply", "--dry-run=server", "--validate=strict", "-f", "-", input=manifest,
                         check=False)

    assert result.returncode == 0, result.stderr
