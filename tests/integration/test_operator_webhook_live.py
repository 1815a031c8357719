"""The real kube-apiserver asks the operator's admission webhook about every new RobotJob.

The operator runs in-process with its webhook on 127.0.0.1 (a serving
certificate from the test bed's CA); a ValidatingWebhookConfiguration, like
the chart's but with a ``url`` instead of a Service and scoped to this
module's namespace, points the API server at it. Jobs whose ``spec.args`` is
too deep or too large are refused at ``kubectl apply`` with the limit and the
field; normal jobs are admitted and bound; the operator stays up.

These configurations use ``failurePolicy: Fail`` so that a webhook that does
not answer shows up as a failed test, not as a silently admitted job; the
chart's default (``Ignore``, the operator's InvalidSpec as the backstop) is
the last test.
"""

from __future__ import annotations

import base64
import json
import time
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import kopf
import pytest
import yaml
from armnet_core.api import API_VERSION, GROUP, ROBOTJOBS, VERSION
from armnet_operator.admission import WEBHOOK_PATH
from armnet_operator.args import MAX_ARGS_BYTES, MAX_ARGS_DEPTH
from armnet_operator.handlers import build_registry
from armnet_testbed.procs import free_port
from kopf.testing import KopfRunner

from tests.integration.operator_bed import Bed, operator_settings

pytestmark = pytest.mark.integration
WEBHOOK_NAME = f"{ROBOTJOBS}.{GROUP}"


def deep_json(levels: int) -> str:
    """Built as text: encoding a deep dict would itself need the recursion headroom."""
    return '{"a":' * (levels - 1) + '{"leaf":1}' + "}" * (levels - 1)


def webhook_configuration(name: str, namespace: str, url: str, ca: Path, failure_policy: str) -> dict[str, Any]:
    return {
        "apiVersion": "admissionregistration.k8s.io/v1", "kind": "ValidatingWebhookConfiguration",
        "metadata": {"name": name},
        "webhooks": [{
            "name": WEBHOOK_NAME,
            "clientConfig": {"url": url, "caBundle": base64.b64encode(ca.read_bytes()).decode()},
            "rules": [{"apiGroups": [GROUP], "apiVersions": [VERSION], "operations": ["CREATE"],
                       "resources": [ROBOTJOBS], "scope": "Namespaced"}],
            "namespaceSelector": {"matchLabels": {"kubernetes.io/metadata.name": namespace}},
            "failurePolicy": failure_policy, "sideEffects": "None", "admissionReviewVersions": ["v1"],
            "timeoutSeconds": 5,
        }],
    }


def job_doc(bed: Bed, name: str, args: Any = None) -> dict[str, Any]:
    spec: dict[str, Any] = {"image": "localhost/armnet-test:dev", "embodiment": bed.embodiment}
    if args is not None:
        spec["args"] = args
    return {"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name, "namespace": bed.ns},
            "spec": spec}


def deep_job_json(bed: Bed, name: str, levels: int) -> str:
    head = json.dumps(job_doc(bed, name))
    return head[:-2] + ', "args": ' + deep_json(levels) + "}}"


def registered(bed: Bed, config: dict[str, Any]) -> None:
    """Apply the configuration and wait until the API server calls it (its webhook cache lags a little)."""
    bed.k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(config))
    probe = deep_job_json(bed, "probe", MAX_ARGS_DEPTH + 1)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        result = bed.k8s.kubectl("create", "--dry-run=server", "-f", "-", input=probe, check=False)
        if "admission webhook" in result.stderr:
            return
        time.sleep(0.2)
    raise AssertionError("the API server never called the webhook")


@dataclass
class Live:
    bed: Bed
    controller: Any
    port: int
    metrics_port: int

    def refused(self, *kubectl: str, input: str) -> str:
        result = self.bed.k8s.kubectl(*kubectl, "-f", "-", input=input, check=False)
        assert result.returncode != 0, f"admitted: {input[:200]}"
        return str(result.stderr)

    def metric(self, name: str, label: str, value: str) -> float:
        text = urllib.request.urlopen(f"http://127.0.0.1:{self.metrics_port}/metrics", timeout=5).read().decode()
        line = next(ln for ln in text.splitlines() if ln.startswith(f'{name}{{{label}="{value}"}}'))
        return float(line.split()[-1])


@pytest.fixture(scope="module")
def live(k8s: Any) -> Iterator[Live]:
    namespace = k8s.create_namespace("webhook")
    cert, key = k8s.pki.serving_cert("armnet-webhook", ("127.0.0.1",))
    port, metrics_port = free_port(), free_port()
    settings = operator_settings(k8s, namespace, webhook_port=port, webhook_address="127.0.0.1",
                                 webhook_cert_file=str(cert), webhook_key_file=str(key),
                                 metrics_port=metrics_port, metrics_address="127.0.0.1")
    config_name = f"armnet-robotjobs-{namespace}"
    bed = Bed(k8s, namespace)
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv("KUBECONFIG", str(k8s.kubeconfig))  # kopf's own login
            registry, controller = build_registry(settings)
            kopf_settings = kopf.OperatorSettings()
            kopf_settings.watching.server_timeout = 10
            args = ["run", "--standalone", "--namespace", namespace]
            with KopfRunner(args, registry=registry, settings=kopf_settings, timeout=120) as runner:
                try:
                    registered(bed, webhook_configuration(
                        config_name, namespace, f"https://127.0.0.1:{port}{WEBHOOK_PATH}", k8s.pki.ca_cert, "Fail"))
                    yield Live(bed, controller, port, metrics_port)
                finally:
                    k8s.kubectl("delete", "validatingwebhookconfiguration", config_name, "--ignore-not-found",
                                check=False)
            assert runner.exception is None, runner.output
            assert runner.exit_code == 0, runner.output
            assert "Traceback" not in runner.output, runner.output
    finally:
        bed.close()
        k8s.delete_namespace(namespace)


def test_a_job_with_args_40_levels_deep_is_refused_at_apply_naming_the_field_and_the_limit(live: Live) -> None:
    doc = job_doc(live.bed, "deep-40", json.loads(deep_json(40)))
    said = live.refused("apply", input=yaml.safe_dump(doc))
    assert f'admission webhook "{WEBHOOK_NAME}" denied the request' in said
    assert f"spec.args is nested more than {MAX_ARGS_DEPTH} levels deep (limit {MAX_ARGS_DEPTH})" in said
    assert live.bed.get_job("deep-40") is None


def test_a_job_with_100_KiB_of_args_is_refused_at_apply_naming_the_field_and_the_limit(live: Live) -> None:
    doc = job_doc(live.bed, "big-100k", {"blob": "x" * (100 * 1024)})
    said = live.refused("apply", input=yaml.safe_dump(doc))
    assert f'admission webhook "{WEBHOOK_NAME}" denied the request' in said
    assert f"spec.args is larger than {MAX_ARGS_BYTES} bytes as JSON (limit {MAX_ARGS_BYTES})" in said
    assert live.bed.get_job("big-100k") is None


def test_args_5000_levels_deep_are_refused_and_the_operator_stays_up(live: Live) -> None:
    said = live.refused("create", input=deep_job_json(live.bed, "deep-5000", 5_000))
    assert "nested more than 32 levels deep" in said
    assert not live.controller.dead
    assert live.metric("armnet_admission_rejections_total", "limit", "depth") >= 1


def test_a_megabyte_of_args_is_refused_by_the_webhook_not_failed_by_its_size(live: Live) -> None:
    doc = json.dumps(job_doc(live.bed, "huge", {"blob": "x" * (1 << 20)}))
    said = live.refused("create", input=doc)
    assert f'admission webhook "{WEBHOOK_NAME}" denied the request: spec.args is larger than' in said


def test_a_normal_job_is_admitted_and_bound(live: Live) -> None:
    cell = live.bed.cell("c1")
    live.bed.apply(job_doc(live.bed, "normal", {"episodes": 3, "poses": [[0.1, 0.2, 0.3]] * 20, "task": "pick"}))
    live.bed.wait_job("normal", phase="dispatched", cellName=cell)
    assert live.metric("armnet_admission_requests_total", "outcome", "allowed") >= 1
    assert not live.controller.dead


def test_with_failure_policy_ignore_a_job_is_admitted_while_no_webhook_answers(k8s: Any, namespace: str) -> None:
    """The chart's default: the operator's InvalidSpec is the backstop (tested in test_operator_hostile_live.py)."""
    bed = Bed(k8s, namespace)
    name = f"armnet-robotjobs-{namespace}"
    url = f"https://127.0.0.1:{free_port()}{WEBHOOK_PATH}"  # nothing listens there
    try:
        k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(
            webhook_configuration(name, namespace, url, k8s.pki.ca_cert, "Ignore")))
        bed.wait("the deep job admitted", lambda: k8s.kubectl(
            "create", "-f", "-", input=deep_job_json(bed, "deep-admitted", 40), check=False).returncode == 0,
            timeout=20)
        assert bed.get_job("deep-admitted") is not None
    finally:
        k8s.kubectl("delete", "validatingwebhookconfiguration", name, "--ignore-not-found", check=False)
        bed.close()
