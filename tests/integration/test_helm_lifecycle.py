"""`helm install`, `upgrade` and `uninstall` of the chart against the test bed's API server.

Only the API objects: the test bed runs no controller-manager or scheduler, so the
Deployment and DaemonSet create no pods here (running the shipped images on the
test-bed node is tests/images/test_helm_install_node.py). What this pins: the
documented adoption of CRDs left by an earlier release works, an upgrade applies
the CRD templates (Helm's crds/ folder would not), and an uninstall keeps the CRDs
and the tenants' RobotJobs.
"""

from __future__ import annotations

import json
import uuid

import pytest
from armnet_core.api import GROUP, ROBOTJOBS
from armnet_testbed.kube import ControlPlane

from tests.support.helm import CHART, CRDS, adopt_crds, helm_on

pytestmark = pytest.mark.integration


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
        crd = json.loads(k8s.kubectl("get", "crd", f"{ROBOTJOBS}.{GROUP}", "-o", "json").stdout)

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
