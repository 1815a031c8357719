"""`helm install`, `upgrade` and `uninstall` of the chart against the test bed's API server.

Only the API objects: the test bed runs no controller-manager or scheduler, so the
Deployment and DaemonSet create no pods here (running the shipped images on the
test-bed node is the "install for real" part of issue 14). What this pins: the
documented adoption of CRDs left by an earlier release works, an upgrade applies
the CRD templates (Helm's crds/ folder would not), and an uninstall keeps the CRDs
and the tenants' RobotJobs.
"""

from __future__ import annotations

import json
import subprocess
import uuid
from typing import Any

import pytest
import yaml

from tests.integration.test_helm_chart import CHART, helm_binary
from tests.testbed.kube import ControlPlane

pytestmark = pytest.mark.integration

CRDS = ("cells.armnet.io", "robotjobs.armnet.io")


def helm_on(k8s: ControlPlane, *args: str, values: dict[str, Any] | None = None) -> subprocess.CompletedProcess[str]:
    argv = [str(helm_binary()), *args, f"--kubeconfig={k8s.kubeconfig}"]
    if values is not None:
        argv += ["--values", "-"]
    result = subprocess.run(argv, input=yaml.safe_dump(values) if values is not None else None,
                            capture_output=True, text=True, timeout=180, check=False)
    assert result.returncode == 0, f"helm {' '.join(args)} failed:\n{result.stderr}"
    return result


def adopt_crds(k8s: ControlPlane, release: str, namespace: str) -> None:
    """docs/helm.md: how a new release takes over CRDs an earlier one left behind."""
    for crd in CRDS:
        k8s.kubectl("label", "crd", crd, "app.kubernetes.io/managed-by=Helm", "--overwrite")
        k8s.kubectl("annotate", "crd", crd, f"meta.helm.sh/release-name={release}",
                    f"meta.helm.sh/release-namespace={namespace}", "--overwrite")


def test_install_upgrade_uninstall_keeps_crds_and_robotjobs(k8s: ControlPlane, namespace: str) -> None:
    release = f"life-{uuid.uuid4().hex[:6]}"
    team = k8s.create_namespace("helm-life-team")
    values = {"jobNamespaces": [{"name": team}]}
    try:
        adopt_crds(k8s, release, namespace)
        helm_on(k8s, "install", release, str(CHART), "-n", namespace, values=values)
        k8s.kubectl("apply", "-n", team, "-f", "-", input=json.dumps({
            "apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob", "metadata": {"name": "keep-me"},
            "spec": {"image": "localhost/job:dev", "embodiment": "lerobot/so-101"}}))

        helm_on(k8s, "upgrade", release, str(CHART), "-n", namespace,
                values={**values, "operator": {"replicas": 3}, "commonLabels": {"armnet.io/upgraded": "yes"}})
        deployment = json.loads(k8s.kubectl("get", "deployment", f"{release}-armnet-operator", "-n", namespace,
                                            "-o", "json").stdout)
        crd = json.loads(k8s.kubectl("get", "crd", "robotjobs.armnet.io", "-o", "json").stdout)

        assert deployment["spec"]["replicas"] == 3
        assert crd["metadata"]["labels"]["armnet.io/upgraded"] == "yes"  # the upgrade applied the CRD
        assert crd["metadata"]["annotations"]["helm.sh/resource-policy"] == "keep"

        helm_on(k8s, "uninstall", release, "-n", namespace)

        assert k8s.kubectl("get", "crd", *CRDS).returncode == 0
        assert k8s.kubectl("get", "robotjob", "keep-me", "-n", team).returncode == 0
        gone = k8s.kubectl("get", "deployment", f"{release}-armnet-operator", "-n", namespace, check=False)
        assert "NotFound" in gone.stderr
        assert "NotFound" in k8s.kubectl("get", "clusterrole", f"{release}-armnet-operator",
                                         check=False).stderr
    finally:
        k8s.kubectl("delete", "robotjob", "keep-me", "-n", team, "--ignore-not-found", "--wait=false",
                    check=False)
        k8s.delete_namespace(team)
