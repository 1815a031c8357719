"""Finding the cluster and the namespace like kubectl, and typed errors from apiserver answers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from armnet_client.errors import (
    ClientError,
    Conflict,
    CrdsMissing,
    Forbidden,
    InvalidJob,
    JobNotFound,
    NamespaceNotFound,
    NoClusterConfigured,
)
from armnet_client.kube import (
    ClusterTarget,
    choose_kubeconfig,
    choose_namespace,
    connect,
    translate,
)
from armnet_core.api import GROUP, ROBOTJOBS

pytestmark = pytest.mark.unit


def test_an_explicit_kubeconfig_wins(tmp_path: Path) -> None:
    flag = tmp_path / "a"
    flag.write_text("x")
    env = tmp_path / "b"
    env.write_text("x")

    assert choose_kubeconfig(str(flag), {"KUBECONFIG": str(env)}, tmp_path / "home") == str(flag)


def test_a_missing_explicit_kubeconfig_is_an_error_not_a_fallback(tmp_path: Path) -> None:
    with pytest.raises(NoClusterConfigured, match="does not exist"):
        choose_kubeconfig(str(tmp_path / "nope"), {}, tmp_path / "home")


def test_kubeconfig_env_lists_are_merged_keeping_existing_files(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    a.write_text("x")
    b.write_text("x")
    listed = f"{a}:{tmp_path / 'missing'}:{b}"

    assert choose_kubeconfig(None, {"KUBECONFIG": listed}, tmp_path / "home") == f"{a}:{b}"


def test_the_home_kubeconfig_is_the_last_file_resort(tmp_path: Path) -> None:
    home = tmp_path / "config"
    home.write_text("x")

    assert choose_kubeconfig(None, {}, home) == str(home)
    assert choose_kubeconfig(None, {}, tmp_path / "absent") is None


@pytest.mark.parametrize(("flag", "context_ns", "pod_ns", "chosen"), [
    ("a", "b", "c", "a"), (None, "b", "c", "b"), (None, None, "c", "c"), (None, None, None, "default"),
])
def test_namespace_order_is_flag_context_pod_default(
    flag: str | None, context_ns: str | None, pod_ns: str | None, chosen: str
) -> None:
    assert choose_namespace(flag, context_ns, pod_ns) == chosen


def test_no_kubeconfig_outside_a_pod_says_no_cluster_is_configured(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("armnet_client.kube.DEFAULT_KUBECONFIG", tmp_path / "absent")

    with pytest.raises(NoClusterConfigured, match="no cluster configured"):
        connect(ClusterTarget(), env={})


def _kubeconfig(path: Path, namespace: str | None) -> Path:
    context: dict[str, str] = {"cluster": "c", "user": "u"}
    if namespace:
        context["namespace"] = namespace
    path.write_text(json.dumps({
        "apiVersion": "v1", "kind": "Config", "current-context": "one",
        "clusters": [{"name": "c", "cluster": {"server": "https://127.0.0.1:1"}}],
        "users": [{"name": "u", "user": {"token": "t"}}],
        "contexts": [{"name": "one", "context": context},
                     {"name": "two", "context": {"cluster": "c", "user": "u", "namespace": "ns-two"}}],
    }))
    return path


def test_the_current_contexts_namespace_is_used(tmp_path: Path) -> None:
    path = _kubeconfig(tmp_path / "kc", "team-a")

    connection = connect(ClusterTarget(kubeconfig=str(path)), env={})

    assert (connection.namespace, connection.context) == ("team-a", "one")


def test_context_flag_selects_another_context_and_its_namespace(tmp_path: Path) -> None:
    path = _kubeconfig(tmp_path / "kc", None)

    connection = connect(ClusterTarget(kubeconfig=str(path), context="two"), env={})

    assert (connection.namespace, connection.context) == ("ns-two", "two")


def test_an_unknown_context_names_the_ones_there_are(tmp_path: Path) -> None:
    path = _kubeconfig(tmp_path / "kc", None)

    with pytest.raises(NoClusterConfigured, match="contexts: one, two"):
        connect(ClusterTarget(kubeconfig=str(path), context="three"), env={})


STATUS_BODY = json.dumps({"kind": "Status", "message": "robotjobs is forbidden: User \"tenant-b\""})


def not_found(message: str, **details: str) -> str:
    """A 404 ``Status`` body as the apiserver sends it (``details`` name what is missing, if anything)."""
    return json.dumps({"kind": "Status", "apiVersion": "v1", "status": "Failure", "message": message,
                       "reason": "NotFound", "details": details, "code": 404})


def test_404_on_a_named_job_is_job_not_found_with_its_namespace() -> None:
    body = not_found(f'{ROBOTJOBS}.{GROUP} "pick-1" not found', name="pick-1", group=GROUP, kind=ROBOTJOBS)
    error = translate(404, body, verb="get", resource=ROBOTJOBS, namespace="team-a", name="pick-1")

    assert isinstance(error, JobNotFound)
    assert "'pick-1' not found in namespace 'team-a'" in str(error)


def test_404_naming_the_namespace_says_the_namespace_is_missing_not_the_crds() -> None:
    body = not_found('namespaces "no-such-namespace" not found', name="no-such-namespace", kind="namespaces")
    error = translate(404, body, verb="create", resource="robotjobs", namespace="no-such-namespace")

    assert isinstance(error, NamespaceNotFound)
    assert str(error).startswith("namespace 'no-such-namespace' does not exist on this cluster")
    assert "CRD" not in str(error)


@pytest.mark.parametrize("name", ["pick-1", None])
def test_404_naming_nothing_is_a_resource_the_cluster_does_not_serve(name: str | None) -> None:
    body = not_found("the server could not find the requested resource")
    error = translate(404, body, verb="get", resource="robotjobs", namespace="team-a", name=name)

    assert isinstance(error, CrdsMissing)
    assert "the armnet CRDs are not installed" in str(error)


def test_403_is_forbidden_naming_verb_and_namespace() -> None:
    error = translate(403, STATUS_BODY, verb="cancel", resource="robotjobs", namespace="team-a")

    assert isinstance(error, Forbidden)
    assert "you may not cancel robotjobs in namespace 'team-a'" in str(error)


@pytest.mark.parametrize(("status", "kind"), [(422, InvalidJob), (400, InvalidJob), (409, Conflict),
                                              (500, ClientError), (401, ClientError)])
def test_other_answers_are_typed(status: int, kind: type[ClientError]) -> None:
    assert isinstance(translate(status, STATUS_BODY, verb="create", resource="robotjobs", namespace="a"), kind)
