"""The test bed's control plane is a real one: schemas, RBAC, watches and SA tokens work."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
import yaml
from armnet_testbed.kube import ControlPlane

pytestmark = pytest.mark.integration

REPO_ROOT = Path(__file__).resolve().parents[2]


def widget(name: str, **spec: object) -> str:
    return json.dumps({"apiVersion": "testbed.armnet.io/v1", "kind": "Widget",
                       "metadata": {"name": name}, "spec": spec})


def test_apiserver_accepts_a_widget_that_matches_the_crd_schema(k8s: ControlPlane, namespace: str) -> None:
    k8s.kubectl("apply", "-n", namespace, "-f", "-", input=widget("ok", size=3, color="red"))

    stored = json.loads(k8s.kubectl("get", "widget", "ok", "-n", namespace, "-o", "json").stdout)
    assert stored["spec"] == {"size": 3, "color": "red"}


def test_apiserver_rejects_a_widget_that_violates_the_crd_schema(k8s: ControlPlane, namespace: str) -> None:
    result = k8s.kubectl("apply", "-n", namespace, "-f", "-", check=False,
                         input=widget("bad", size=0, color="blue"))

    assert result.returncode != 0
    assert "spec.size" in result.stderr and "spec.color" in result.stderr, result.stderr
    missing = k8s.kubectl("get", "widget", "bad", "-n", namespace, check=False)
    assert "NotFound" in missing.stderr


def test_apiserver_enforces_cel_rules_of_the_crd(k8s: ControlPlane, namespace: str) -> None:
    result = k8s.kubectl("apply", "-n", namespace, "-f", "-", check=False,
                         input=widget("tiny-green", size=1, color="green"))

    assert result.returncode != 0
    assert "green widgets must have size >= 2" in result.stderr, result.stderr


def _robotjob_crd() -> dict | None:
    for path in sorted((REPO_ROOT / "crds").glob("*.yaml")):
        for doc in yaml.safe_load_all(path.read_text()):
            if isinstance(doc, dict) and doc.get("kind") == "CustomResourceDefinition" \
                    and doc["spec"]["names"]["kind"] == "RobotJob":
                return doc
    return None


def test_apiserver_rejects_a_robotjob_that_violates_the_crd_schema(k8s: ControlPlane, namespace: str) -> None:
    crd = _robotjob_crd()
    if crd is None:
        pytest.fail("crds/ has no RobotJob CustomResourceDefinition yet (crds/robotjob.yaml)")
    api_version = f"{crd['spec']['group']}/{crd['spec']['versions'][0]['name']}"
    job = {"apiVersion": api_version, "kind": "RobotJob", "metadata": {"name": "bad-timeout"},
           "spec": {"image": "localhost/job:dev", "embodiment": "lerobot/so-101",
                    "timeoutSeconds": 0}}
    no_embodiment = {"apiVersion": api_version, "kind": "RobotJob",
                     "metadata": {"name": "no-embodiment"},
                     "spec": {"image": "localhost/job:dev"}}

    bad_timeout = k8s.kubectl("apply", "-n", namespace, "-f", "-", input=json.dumps(job), check=False)
    missing = k8s.kubectl("apply", "-n", namespace, "-f", "-", input=json.dumps(no_embodiment),
                          check=False)

    assert bad_timeout.returncode != 0 and "timeoutSeconds" in bad_timeout.stderr, bad_timeout.stderr
    assert missing.returncode != 0 and "embodiment" in missing.stderr, missing.stderr


def _grant_secret_reader(k8s: ControlPlane, namespace: str, user: str) -> None:
    k8s.kubectl("create", "role", "secret-reader", "-n", namespace, "--verb=get,list",
                "--resource=secrets")
    k8s.kubectl("create", "rolebinding", "secret-reader", "-n", namespace, "--role=secret-reader",
                f"--user={user}")


def test_rbac_lets_a_tenant_read_secrets_only_in_its_own_namespace(k8s: ControlPlane, namespace: str) -> None:
    other = k8s.create_namespace("other-tenant")
    try:
        for ns in (namespace, other):
            k8s.kubectl("create", "secret", "generic", "creds", "-n", ns, "--from-literal=k=v")
        _grant_secret_reader(k8s, namespace, "tenant-a")
        tenant = k8s.user("tenant-a")

        own = k8s.kubectl("get", "secret", "creds", "-n", namespace, "-o", "name", user=tenant,
                          check=False)
        foreign = k8s.kubectl("get", "secret", "creds", "-n", other, user=tenant, check=False)
        listing = k8s.kubectl("get", "secrets", "-n", other, user=tenant, check=False)
    finally:
        k8s.delete_namespace(other)

    assert own.returncode == 0 and own.stdout.strip() == "secret/creds", own.stderr
    assert foreign.returncode != 0
    assert 'User "tenant-a" cannot get resource "secrets"' in foreign.stderr, foreign.stderr
    assert "Forbidden" in listing.stderr, listing.stderr


def test_rbac_sees_a_certificate_user_with_its_groups(k8s: ControlPlane, namespace: str) -> None:
    alice = k8s.user("alice", ["acme:researchers"])
    # A Role of our own: the built-in view/edit/admin ClusterRoles are filled by the
    # controller-manager's aggregation controller, which this plane does not run.
    k8s.kubectl("create", "role", "cm-reader", "-n", namespace, "--verb=list",
                "--resource=configmaps")
    k8s.kubectl("create", "rolebinding", "cm-reader-for-acme", "-n", namespace, "--role=cm-reader",
                "--group=acme:researchers")

    allowed = k8s.kubectl("get", "configmaps", "-n", namespace, user=alice, check=False)
    denied = k8s.kubectl("get", "configmaps", "-n", "default", user=alice, check=False)

    assert allowed.returncode == 0, allowed.stderr
    assert 'User "alice" cannot list resource "configmaps"' in denied.stderr, denied.stderr


def test_a_watch_sees_an_update(k8s: ControlPlane, namespace: str) -> None:
    from kubernetes import client, watch

    core = client.CoreV1Api(k8s.api_client())
    created = core.create_namespaced_config_map(
        namespace, client.V1ConfigMap(metadata=client.V1ObjectMeta(name="cm"), data={"v": "1"}))
    core.patch_namespaced_config_map("cm", namespace, {"data": {"v": "2"}})

    stream = watch.Watch().stream(core.list_namespaced_config_map, namespace,
                                  resource_version=created.metadata.resource_version,
                                  timeout_seconds=20)
    event = next(stream)

    assert event["type"] == "MODIFIED"
    assert event["object"].data == {"v": "2"}


def test_service_account_tokens_from_the_issuer_authenticate(k8s: ControlPlane, namespace: str) -> None:
    k8s.kubectl("create", "serviceaccount", "robot", "-n", namespace)
    token = k8s.kubectl("create", "token", "robot", "-n", namespace).stdout.strip()

    result = subprocess.run(
        [k8s.kubectl_path, f"--server={k8s.url}", f"--token={token}",
         f"--certificate-authority={k8s.pki.ca_cert}", "auth", "whoami", "-o", "json"],
        capture_output=True, text=True, timeout=30, check=False)

    assert result.returncode == 0, result.stderr
    who = json.loads(result.stdout)["status"]["userInfo"]
    assert who["username"] == f"system:serviceaccount:{namespace}:robot"
