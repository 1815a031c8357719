"""The chart deploys the cell operator's page (`armnet fms`, docs/fms.md) when fms.enabled.

Real `helm`, the FMS's own option and token parsing on the rendered Secret, the test
bed's real kube-apiserver for a server-side dry-run and for what the rendered
ServiceAccount may do, and a real nats-server with the chart's nats.conf for the fms user
(the FMS's own NATS client, `armnet_fms.bus.Bus`, on one side; the agent user on the other).
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_testbed.kube import ControlPlane

from tests.support import helm_nats
from tests.support.fms_objects import FMS_RULES
from tests.support.helm import ALL_OPTIONS, CHART, find, helm, helm_on, render
from tests.support.helm_nats import Server, connect, run, settle, violated

pytestmark = pytest.mark.integration

TOKENS = [{"name": "maria", "token": "maria-token-0123456789"}, {"name": "lee@lab-1", "token": "lee-token-0123456789ab"}]
#: The chart's nats.conf (auth on) in a real nats-server: the fixture test_helm_nats.py uses.
server = helm_nats.server

ENABLED = {"fms": {"enabled": True, "operators": TOKENS}}


def fms_objects(objects: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [o for o in objects if o["metadata"].get("labels", {}).get("app.kubernetes.io/component") == "fms"]


def container(objects: list[dict[str, Any]]) -> dict[str, Any]:
    (fms,) = find(objects, "Deployment", "-fms")["spec"]["template"]["spec"]["containers"]
    return dict(fms)


def env_of(objects: list[dict[str, Any]]) -> dict[str, Any]:
    return {e["name"]: e.get("value", e.get("valueFrom")) for e in container(objects).get("env", [])}


def render_fails(values: dict[str, Any]) -> str:
    result = helm("template", "x", str(CHART), "--values", "-", input=yaml.safe_dump(values), check=False)
    assert result.returncode != 0, "helm rendered values it should refuse"
    return result.stderr


# ---------------------------------------------------------------------------- what is rendered
def test_fms_is_not_deployed_by_default() -> None:
    assert fms_objects(render()) == []
    assert not [o for o in render() if o["metadata"]["name"].endswith("-fms")]


def test_enabled_fms_renders_its_deployment_service_account_rbac_and_secret() -> None:
    kinds = sorted(o["kind"] for o in fms_objects(render(values=ENABLED)))

    assert kinds == ["ClusterRole", "ClusterRoleBinding", "Deployment", "Secret", "Service", "ServiceAccount"]


def test_cluster_role_is_exactly_the_rules_the_service_is_tested_with() -> None:
    role = find(render(values=ENABLED), "ClusterRole", "-fms")

    assert role["rules"] == FMS_RULES


def test_cluster_role_binds_the_fms_service_account_the_deployment_runs_as() -> None:
    objects = render(values=ENABLED)
    binding = find(objects, "ClusterRoleBinding", "-fms")
    account = find(objects, "ServiceAccount", "-fms")["metadata"]
    pod = find(objects, "Deployment", "-fms")["spec"]["template"]["spec"]

    assert binding["roleRef"]["name"] == find(objects, "ClusterRole", "-fms")["metadata"]["name"]
    assert binding["subjects"] == [{"kind": "ServiceAccount", "name": account["name"],
                                    "namespace": account["namespace"]}]
    assert pod["serviceAccountName"] == account["name"]


def test_deployment_runs_armnet_fms_with_the_mounted_operators_file_and_session_key() -> None:
    objects = render(values=ENABLED)
    fms = container(objects)
    volumes = {v["name"]: v for v in find(objects, "Deployment", "-fms")["spec"]["template"]["spec"]["volumes"]}
    mount = next(m for m in fms["volumeMounts"] if m["mountPath"] == "/etc/armnet-fms")

    assert fms["args"] == ["fms", "--operators-file", "/etc/armnet-fms/operators",
                           "--session-key-file", "/etc/armnet-fms/session-key"]
    assert mount["readOnly"] is True
    assert volumes[mount["name"]]["secret"]["secretName"] == find(objects, "Secret", "-fms")["metadata"]["name"]


def test_deployment_uses_the_operator_image_unless_told_otherwise() -> None:
    objects = render(values={**ENABLED, "image": {"operatorRepository": "reg.example/op", "tag": "1.2.3"}})
    other = render(values={"fms": {**ENABLED["fms"], "image": {"repository": "reg.example/fms", "tag": "9"}}})

    assert container(objects)["image"] == "reg.example/op:1.2.3"
    assert container(other)["image"] == "reg.example/fms:9"


def test_pod_runs_as_non_root_on_a_read_only_root_with_no_capabilities() -> None:
    objects = render(values=ENABLED)
    pod = find(objects, "Deployment", "-fms")["spec"]["template"]["spec"]
    security = container(objects)["securityContext"]

    assert pod["securityContext"]["runAsNonRoot"] is True
    assert pod["automountServiceAccountToken"] is False
    assert security["readOnlyRootFilesystem"] is True
    assert security["allowPrivilegeEscalation"] is False
    assert security["capabilities"] == {"drop": ["ALL"]}
    assert container(objects)["resources"]["limits"]["memory"]


def test_readiness_is_healthz_on_the_port_the_service_exposes() -> None:
    objects = render(values=ENABLED)
    fms = container(objects)
    service = find(objects, "Service", "-fms")["spec"]

    assert fms["readinessProbe"]["httpGet"] == {"path": "/healthz", "port": "http"}
    assert fms["ports"] == [{"name": "http", "containerPort": 8080, "protocol": "TCP"}]
    assert env_of(objects)["ARMNET_FMS_PORT"] == "8080"
    assert service["type"] == "ClusterIP"
    assert service["ports"] == [{"name": "http", "port": 8080, "targetPort": "http", "protocol": "TCP"}]


def test_replicas_are_as_configured() -> None:
    objects = render(values={"fms": {**ENABLED["fms"], "replicas": 3}})

    assert find(objects, "Deployment", "-fms")["spec"]["replicas"] == 3


def test_site_and_trusted_header_reach_the_service_as_its_env() -> None:
    values = {"fms": {**ENABLED["fms"], "site": "lab-1", "trustedHeader": "X-Forwarded-User",
                      "networkPolicy": {"proxyPodSelector": {"matchLabels": {"app": "oauth2-proxy"}}}}}
    env = env_of(render(values=values))

    assert (env["ARMNET_FMS_SITE"], env["ARMNET_FMS_TRUSTED_HEADER"]) == ("lab-1", "X-Forwarded-User")
    assert "ARMNET_FMS_SITE" not in env_of(render(values=ENABLED))
    assert "ARMNET_FMS_TRUSTED_HEADER" not in env_of(render(values=ENABLED))


def test_service_monitor_scrapes_the_fms_metrics_when_monitoring_is_on() -> None:
    objects = render(values={**ENABLED, "metrics": {"serviceMonitor": {"enabled": True}}})
    monitor = find(objects, "ServiceMonitor", "-fms")
    service = find(objects, "Service", "-fms")

    assert monitor["spec"]["selector"]["matchLabels"].items() <= service["metadata"]["labels"].items()
    assert monitor["spec"]["endpoints"][0]["port"] == service["spec"]["ports"][0]["name"]
    assert monitor["spec"]["endpoints"][0]["path"] == "/metrics"
    assert not [o for o in render(values=ENABLED) if o["kind"] == "ServiceMonitor"]


# ---------------------------------------------------------------------------- the Secret
def secret_files(objects: list[dict[str, Any]], tmp_path: Path) -> argparse.Namespace:
    """Write the rendered Secret's keys as the pod would see them; the FMS's own CLI args."""
    data = find(objects, "Secret", "-fms")["data"]
    for key in ("operators", "session-key"):
        (tmp_path / key).write_bytes(base64.b64decode(data[key]))
    return argparse.Namespace(operators_file=str(tmp_path / "operators"),
                              session_key_file=str(tmp_path / "session-key"), trusted_header="")


def test_generated_secret_is_accepted_by_the_fms_with_the_operators_from_values(tmp_path: Path) -> None:
    from armnet_fms.cli import load_auth

    auth = load_auth(secret_files(render(values=ENABLED), tmp_path))

    assert auth.tokens == {t["token"]: t["name"] for t in TOKENS}
    assert len(auth.secret_key) >= 32


def test_each_fresh_install_gets_its_own_random_session_key() -> None:
    keys = {find(render(release=f"r{i}", values=ENABLED), "Secret", "-fms")["data"]["session-key"] for i in range(2)}

    assert len(keys) == 2


def test_an_existing_secret_replaces_the_generated_one() -> None:
    objects = render(values={"fms": {"enabled": True, "existingSecret": "fms-operators"}})
    volumes = find(objects, "Deployment", "-fms")["spec"]["template"]["spec"]["volumes"]

    assert not [o for o in objects if o["kind"] == "Secret" and o["metadata"]["name"].endswith("-fms")]
    assert {"name": "fms-secret", "secret": {
        "secretName": "fms-operators", "defaultMode": 0o440,
        "items": [{"key": "operators", "path": "operators"}, {"key": "session-key", "path": "session-key"}]}} in volumes


def test_enabling_the_fms_with_no_way_to_log_in_is_refused() -> None:
    assert "no way to log in" in render_fails({"fms": {"enabled": True}})


def test_an_operator_token_shorter_than_16_characters_is_refused() -> None:
    stderr = render_fails({"fms": {"enabled": True, "operators": [{"name": "a", "token": "short"}]}})

    assert "/fms/operators/0/token" in stderr


# ---------------------------------------------------------------------------- NetworkPolicy
def test_trusted_header_gets_a_network_policy_letting_only_the_proxy_reach_the_port() -> None:
    proxy = {"matchLabels": {"app.kubernetes.io/name": "oauth2-proxy"}}
    objects = render(values={"fms": {**ENABLED["fms"], "trustedHeader": "X-Forwarded-User",
                                     "networkPolicy": {"proxyPodSelector": proxy}}})
    policy = find(objects, "NetworkPolicy", "-fms")["spec"]

    assert policy["podSelector"]["matchLabels"] == find(objects, "Deployment", "-fms")["spec"]["selector"]["matchLabels"]
    assert policy["policyTypes"] == ["Ingress"]
    assert policy["ingress"] == [{"ports": [{"port": 8080, "protocol": "TCP"}], "from": [{"podSelector": proxy}]}]


def test_no_network_policy_without_a_trusted_header() -> None:
    assert not [o for o in render(values=ENABLED) if o["kind"] == "NetworkPolicy"]


def test_trusted_header_with_the_policy_but_no_proxy_selector_is_refused() -> None:
    stderr = render_fails({"fms": {"enabled": True, "trustedHeader": "X-Forwarded-User"}})

    assert "proxyPodSelector" in stderr


# ---------------------------------------------------------------------------- NATS URL
def test_with_the_bundled_nats_and_users_the_fms_connects_as_the_fms_user() -> None:
    values = {**ENABLED, "nats": {"deploy": {"enabled": True, "auth": {"enabled": True, "existingSecret": "users"}}}}
    env = env_of(render("armnet", "armnet-system", values=values))

    assert env["NATS_FMS_PASSWORD"] == {"secretKeyRef": {"name": "users", "key": "fms"}}
    assert env["ARMNET_FMS_NATS_URL"] == "nats://fms:$(NATS_FMS_PASSWORD)@armnet-nats.armnet-system.svc:4222"


def test_the_fms_nats_url_can_come_from_its_own_secret() -> None:
    values = {"fms": {**ENABLED["fms"], "nats": {"existingSecret": {"name": "fms-nats", "key": "url"}}}}

    assert env_of(render(values=values))["ARMNET_FMS_NATS_URL"] == {"secretKeyRef": {"name": "fms-nats", "key": "url"}}


# ---------------------------------------------------------------------------- lint, API server
def test_helm_lint_passes_strict_with_every_option_on_including_the_fms() -> None:
    assert find(render(values_files=[ALL_OPTIONS]), "Deployment", "-fms")
    assert "0 chart(s) failed" in helm("lint", "--strict", str(CHART), "--values", str(ALL_OPTIONS)).stdout


def test_rendered_fms_objects_pass_a_server_side_dry_run(k8s: ControlPlane, namespace: str) -> None:
    values = {"fms": {**ENABLED["fms"], "trustedHeader": "X-Forwarded-User", "site": "lab-1",
                      "networkPolicy": {"proxyPodSelector": {"matchLabels": {"app": "oauth2-proxy"}}}}}
    objects = fms_objects(render("fms-dry-run", namespace, values=values))

    result = k8s.kubectl("apply", "--dry-run=server", "--validate=strict", "-f", "-",
                         input=yaml.safe_dump_all(objects), check=False)

    assert result.returncode == 0, result.stderr
    assert len([line for line in result.stdout.splitlines() if "(server dry run)" in line]) == len(objects)


def test_the_rendered_service_account_may_do_what_the_fms_needs_and_no_more(k8s: ControlPlane, namespace: str) -> None:
    objects = [o for o in fms_objects(render("fms-rbac", namespace, values=ENABLED))
               if o["kind"] in ("ServiceAccount", "ClusterRole", "ClusterRoleBinding")]
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump_all(objects))
    account = f"system:serviceaccount:{namespace}:{find(objects, 'ServiceAccount')['metadata']['name']}"

    def can(*args: str) -> bool:
        return k8s.kubectl("auth", "can-i", "--as", account, *args, check=False).stdout.strip() == "yes"

    try:
        allowed = [can("patch", "cells.armnet.io"), can("watch", "robotjobs.armnet.io", "-A"),
                   can("patch", "robotjobs.armnet.io", "-n", "team-x"), can("create", "events", "-n", "team-x")]
        denied = [can("patch", "cells.armnet.io", "--subresource=status"),
                  can("patch", "robotjobs.armnet.io", "-A", "--subresource=status"),
                  can("delete", "robotjobs.armnet.io", "-A"), can("get", "secrets", "-A"),
                  can("create", "pods", "-n", namespace)]
    finally:
        k8s.kubectl("delete", "-f", "-", "--ignore-not-found", input=yaml.safe_dump_all(objects), check=False)

    assert allowed == [True] * 4
    assert denied == [False] * 5


# ---------------------------------------------------------------------------- the fms NATS user
def fms_url(server: Server) -> str:
    return server.url.replace("nats://", "nats://fms:fms-pw@")


def test_fms_user_hears_reset_notices_and_its_confirmation_reaches_the_agent(server: Server) -> None:
    from armnet_fms.bus import Bus

    async def body(server: Server) -> None:
        heard: list[tuple[str, dict[str, Any]]] = []
        bus = Bus(fms_url(server))
        await bus.start(lambda cell, notice: heard.append((cell, notice)))
        agent = await connect(server, "agent")
        inputs = await agent.subscribe("fms.cell-1.reset.confirm")
        await settle(agent)
        await agent.publish("fms.cell-1.reset.requested", b'{"request": "job-1@1"}')
        await settle(agent)
        for _ in range(50):
            if heard:
                break
            await asyncio.sleep(0.1)
        await bus.publish("fms.cell-1.reset.confirm", b'{"by": "maria", "request": "job-1@1"}')
        confirm = await inputs.next_msg(timeout=5)
        await bus.close()
        await agent.close()

        assert heard == [("cell-1", {"request": "job-1@1"})]
        assert confirm.data == b'{"by": "maria", "request": "job-1@1"}'

    run(server, body)


def test_fms_user_hears_the_agents_telemetry_and_keeps_it_for_the_page(server: Server) -> None:
    from armnet_fms.bus import Bus
    from armnet_fms.telemetry import TelemetryStore

    async def body(server: Server) -> None:
        store = TelemetryStore()
        bus = Bus(fms_url(server), on_telemetry=lambda subject, data: store.accept(subject, data, 100.0))
        await bus.start(lambda cell, notice: None)
        agent = await connect(server, "agent")
        reading = {"t": 1.0, "source": "idle", "arms": {"arm": {"motors": {
            "gripper": {"position": 2048, "load": -12, "temperature": 31}}}}}
        await agent.publish("telemetry.cell-1.servos", json.dumps(reading).encode())
        await agent.publish("telemetry.cell-1.camera.front", b"\xff\xd8\xff\xe0 a jpeg")
        await settle(agent)
        for _ in range(50):
            if store.kept == 2:
                break
            await asyncio.sleep(0.1)
        await bus.close()
        await agent.close()

        assert store.view("cell-1", 100.0)["series"] == [
            {"arm": "arm", "motor": "gripper", "points": [[0.0, 2048, -12, 31]]}]
        frame = store.frame("cell-1", "front")
        assert frame is not None and frame.jpeg == b"\xff\xd8\xff\xe0 a jpeg"

    run(server, body)


def test_fms_user_cannot_read_job_logs_or_other_subjects(server: Server) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        fms = await connect(server, "fms", errors)
        await fms.subscribe("logs.>")
        await fms.subscribe("fms.cell-1.reset.confirm")
        await fms.subscribe("teleop.>")
        await settle(fms)
        await fms.close()

        assert violated(errors, 'Subscription to "logs.>"'), errors
        assert violated(errors, 'Subscription to "fms.cell-1.reset.confirm"'), errors
        assert violated(errors, 'Subscription to "teleop.>"'), errors

    run(server, body)


def test_fms_user_cannot_publish_job_output_or_teleop_input(server: Server) -> None:
    async def body(server: Server) -> None:
        errors: list[str] = []
        fms = await connect(server, "fms", errors)
        await fms.publish("logs.team-a.job-1.stdout", b"forged")
        await fms.publish("teleop.team-a.job-1.action", b"{}")
        await settle(fms)
        await fms.close()

        assert violated(errors, 'Publish to "logs.team-a.job-1.stdout"'), errors
        assert violated(errors, 'Publish to "teleop.team-a.job-1.action"'), errors

    run(server, body)


# ---------------------------------------------------------------------------- upgrades
def test_an_upgrade_keeps_the_generated_session_key_and_takes_the_new_operators(
        k8s: ControlPlane, namespace: str) -> None:
    release = "fms-keep"
    only_fms = {"crds": {"install": False}, "operator": {"enabled": False}, "agent": {"enabled": False},
                "admissionWebhook": {"enabled": False}, "fms": ENABLED["fms"]}

    def secret() -> dict[str, str]:
        data = json.loads(k8s.kubectl("get", "secret", f"{release}-armnet-fms", "-n", namespace, "-o", "json").stdout)
        return {k: base64.b64decode(v).decode() for k, v in data["data"].items()}

    helm_on(k8s, "install", release, str(CHART), "-n", namespace, values=only_fms)
    try:
        before = secret()
        helm_on(k8s, "upgrade", release, str(CHART), "-n", namespace,
                values={**only_fms, "fms": {**ENABLED["fms"], "operators": TOKENS[:1]}})
        after = secret()
    finally:
        helm_on(k8s, "uninstall", release, "-n", namespace)

    assert after["session-key"] == before["session-key"]
    assert after["operators"] == f"{TOKENS[0]['name']}:{TOKENS[0]['token']}\n"


def test_the_fms_gets_read_keys_to_the_outputs_bucket_only_from_its_own_secret() -> None:
    bucket = {"bucket": "outputs", "endpoint": "http://s3.lab:8333", "credentialsSecret": "agent-keys",
              "operatorCredentialsSecret": "ops-keys"}
    # Never the agent's (write) or the operator's (delete) keys: without its own, no video link.
    assert "ARMNET_ARTIFACTS_BUCKET" not in env_of(render(values={**ENABLED, "artifacts": bucket}))
    env = env_of(render(values={**ENABLED, "artifacts": {**bucket, "fmsCredentialsSecret": "fms-read-keys"}}))
    assert (env["ARMNET_ARTIFACTS_BUCKET"], env["ARMNET_ARTIFACTS_ENDPOINT"]) == ("outputs", "http://s3.lab:8333")
    assert env["ARMNET_ARTIFACTS_ACCESS_KEY_ID"] == {"secretKeyRef": {"name": "fms-read-keys", "key": "accessKeyId"}}
    assert env["ARMNET_ARTIFACTS_SECRET_ACCESS_KEY"] == {
        "secretKeyRef": {"name": "fms-read-keys", "key": "secretAccessKey"}}
