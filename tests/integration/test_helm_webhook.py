"""The chart registers the operator's RobotJob admission webhook and gives it a working certificate.

Rendered with the real `helm`; the chart-made certificate is checked with a real
TLS handshake against the operator's own webhook server, under the Service's DNS
name the API server uses. The server-side dry run of the default values
(test_helm_chart.py) covers the new objects too; the API server calling the
webhook is test_operator_webhook_live.py.
"""

from __future__ import annotations

import asyncio
import base64
import ssl
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_core.api import GROUP, ROBOTJOBS, VERSION
from armnet_operator.admission import WEBHOOK_PATH
from armnet_operator.metrics import Metrics
from armnet_operator.webhook import AdmissionWebhook
from armnet_testbed.kube import ControlPlane

from tests.support.helm import CHART, env_of, find, helm, render

pytestmark = pytest.mark.integration


def operator_container(objects: list[dict[str, Any]]) -> dict[str, Any]:
    return dict(find(objects, "Deployment", "-operator")["spec"]["template"]["spec"]["containers"][0])


def webhook_of(objects: list[dict[str, Any]]) -> dict[str, Any]:
    return dict(find(objects, "ValidatingWebhookConfiguration")["webhooks"][0])


def test_the_webhook_is_on_by_default_for_robotjob_creates_only_failing_open() -> None:
    webhook = webhook_of(render())

    assert webhook["name"] == f"{ROBOTJOBS}.{GROUP}"
    assert webhook["rules"] == [{"apiGroups": [GROUP], "apiVersions": [VERSION], "operations": ["CREATE"],
                                 "resources": [ROBOTJOBS], "scope": "Namespaced"}]
    assert webhook["failurePolicy"] == "Ignore"
    assert webhook["sideEffects"] == "None"
    assert webhook["admissionReviewVersions"] == ["v1"]
    assert 1 <= webhook["timeoutSeconds"] <= 30


def test_the_api_server_reaches_the_operator_through_the_webhook_service() -> None:
    objects = render("robots", "ops")
    service = find(objects, "Service", "-operator-webhook")
    deployment = find(objects, "Deployment", "-operator")

    assert webhook_of(objects)["clientConfig"]["service"] == {
        "name": "robots-armnet-operator-webhook", "namespace": "ops", "path": WEBHOOK_PATH, "port": 443}
    assert service["spec"]["ports"] == [{"name": "webhook", "port": 443, "targetPort": "webhook", "protocol": "TCP"}]
    assert service["spec"]["selector"] == deployment["spec"]["selector"]["matchLabels"]
    assert {"name": "webhook", "containerPort": 9443, "protocol": "TCP"} in operator_container(objects)["ports"]


def test_the_operator_serves_the_webhook_from_the_mounted_certificate_secret() -> None:
    objects = render()
    container = operator_container(objects)
    pod = find(objects, "Deployment", "-operator")["spec"]["template"]["spec"]
    env = env_of(container)
    volume = next(v for v in pod["volumes"] if v["name"] == "webhook-tls")
    mount = next(m for m in container["volumeMounts"] if m["name"] == "webhook-tls")

    assert env["ARMNET_OPERATOR_WEBHOOK_PORT"] == "9443"
    assert env["ARMNET_OPERATOR_WEBHOOK_CERT_FILE"] == f"{mount['mountPath']}/tls.crt"
    assert env["ARMNET_OPERATOR_WEBHOOK_KEY_FILE"] == f"{mount['mountPath']}/tls.key"
    assert mount["readOnly"] is True
    assert volume["secret"]["secretName"] == find(objects, "Secret", "-webhook-tls")["metadata"]["name"]


def test_the_chart_made_certificate_is_trusted_by_the_ca_bundle_under_the_service_name(tmp_path: Path) -> None:
    objects = render("robots", "ops")
    secret = find(objects, "Secret", "-webhook-tls")["data"]
    ca_bundle = base64.b64decode(webhook_of(objects)["clientConfig"]["caBundle"])
    cert, key = tmp_path / "tls.crt", tmp_path / "tls.key"
    cert.write_bytes(base64.b64decode(secret["tls.crt"]))
    key.write_bytes(base64.b64decode(secret["tls.key"]))

    async def handshake() -> None:
        server = AdmissionWebhook(Metrics(), str(cert), str(key), "127.0.0.1", 0)
        await server.start()
        try:
            client = ssl.create_default_context(cadata=ca_bundle.decode())
            _, writer = await asyncio.open_connection(
                "127.0.0.1", server.port, ssl=client, server_hostname="robots-armnet-operator-webhook.ops.svc")
            writer.close()
        finally:
            await server.stop()

    asyncio.run(handshake())  # raises ssl.SSLCertVerificationError if the CA or the name were wrong


def test_listed_job_namespaces_are_the_only_ones_the_webhook_judges() -> None:
    webhook = webhook_of(render(values={"jobNamespaces": [{"name": "team-a"}, {"name": "team-b"}]}))

    assert webhook["namespaceSelector"] == {"matchExpressions": [
        {"key": "kubernetes.io/metadata.name", "operator": "In", "values": ["team-a", "team-b"]}]}


def test_fail_closed_is_a_value() -> None:
    assert webhook_of(render(values={"admissionWebhook": {"failurePolicy": "Fail"}}))["failurePolicy"] == "Fail"


def test_cert_manager_writes_the_secret_and_injects_the_ca() -> None:
    objects = render("robots", "ops", values={"admissionWebhook": {"certificate": {"source": "certManager"}}})
    certificate = find(objects, "Certificate")
    issuer = find(objects, "Issuer")
    configuration = find(objects, "ValidatingWebhookConfiguration")

    assert not [o for o in objects if o["kind"] == "Secret" and o["metadata"]["name"].endswith("-webhook-tls")]
    assert certificate["spec"]["secretName"] == "robots-armnet-operator-webhook-tls"
    assert "robots-armnet-operator-webhook.ops.svc" in certificate["spec"]["dnsNames"]
    assert certificate["spec"]["issuerRef"]["name"] == issuer["metadata"]["name"]
    assert issuer["spec"] == {"selfSigned": {}}
    assert configuration["metadata"]["annotations"]["cert-manager.io/inject-ca-from"] == \
        "ops/robots-armnet-operator-webhook"
    assert "caBundle" not in configuration["webhooks"][0]["clientConfig"]


def test_cert_manager_with_an_issuer_of_your_own_makes_no_issuer() -> None:
    issuer_ref = {"name": "corp-ca", "kind": "ClusterIssuer", "group": "cert-manager.io"}
    objects = render(values={"admissionWebhook": {"certificate": {"source": "certManager", "issuerRef": issuer_ref}}})

    assert find(objects, "Certificate")["spec"]["issuerRef"] == issuer_ref
    assert not [o for o in objects if o["kind"] == "Issuer"]


def test_a_pre_created_secret_is_mounted_with_the_ca_bundle_given() -> None:
    ca = base64.b64encode(b"-----BEGIN CERTIFICATE-----\n...\n-----END CERTIFICATE-----\n").decode()
    objects = render(values={"admissionWebhook": {"certificate": {
        "source": "secret", "secretName": "my-webhook-tls", "caBundle": ca}}})
    pod = find(objects, "Deployment", "-operator")["spec"]["template"]["spec"]

    assert next(v for v in pod["volumes"] if v["name"] == "webhook-tls")["secret"]["secretName"] == "my-webhook-tls"
    assert webhook_of(objects)["clientConfig"]["caBundle"] == ca
    assert not [o for o in objects if o["kind"] == "Secret"]


@pytest.mark.parametrize(("certificate", "says"), [
    ({"source": "secret", "caBundle": "Zm9v"}, "admissionWebhook.certificate.secretName"),
    ({"source": "secret", "secretName": "my-webhook-tls"}, "admissionWebhook.certificate.caBundle"),
])
def test_a_pre_created_secret_needs_its_name_and_ca_saying_which(certificate: dict[str, str], says: str) -> None:
    result = helm("template", "armnet", str(CHART), "--values", "-",
                  input=yaml.safe_dump({"admissionWebhook": {"certificate": certificate}}), check=False)

    assert result.returncode != 0 and says in result.stderr, result.stderr


@pytest.mark.parametrize(("values", "path"), [
    ({"admissionWebhook": {"failurePolicy": "Sometimes"}}, "admissionWebhook.failurePolicy"),
    ({"admissionWebhook": {"timeoutSeconds": 60}}, "admissionWebhook.timeoutSeconds"),
    ({"admissionWebhook": {"certificate": {"source": "vault"}}}, "admissionWebhook.certificate.source"),
])
def test_the_schema_rejects_webhook_values_the_api_server_would(values: dict[str, Any], path: str) -> None:
    result = helm("template", "armnet", str(CHART), "--values", "-", input=yaml.safe_dump(values), check=False)

    assert result.returncode != 0
    assert "/" + path.replace(".", "/") in result.stderr, result.stderr


def test_turned_off_there_is_no_webhook_port_certificate_or_registration() -> None:
    objects = render(values={"admissionWebhook": {"enabled": False}})
    container = operator_container(objects)

    assert not [o for o in objects if o["kind"] in ("ValidatingWebhookConfiguration", "Secret")]
    assert not [o for o in objects if o["metadata"]["name"].endswith("-operator-webhook")]
    assert [p["name"] for p in container["ports"]] == ["metrics"]
    assert not any(name.startswith("ARMNET_OPERATOR_WEBHOOK") for name in env_of(container))


def test_an_upgrade_keeps_the_chart_made_certificate(k8s: ControlPlane, namespace: str) -> None:
    """`lookup` finds the Secret of the installed release, so the API server's caBundle stays valid."""
    first = render("keep", namespace)
    secret = find(first, "Secret", "-webhook-tls")
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(secret))

    out = helm("template", "keep", str(CHART), "--namespace", namespace, "--dry-run=server",
               f"--kubeconfig={k8s.kubeconfig}").stdout
    again = [doc for doc in yaml.safe_load_all(out) if doc]

    assert find(again, "Secret", "-webhook-tls")["data"] == secret["data"]
    assert webhook_of(again)["clientConfig"]["caBundle"] == secret["data"]["ca.crt"]
