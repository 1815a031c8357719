"""CellQuotas applied by the real operator on the real API server: a tenant at its quota waits
with QuotaExhausted while another tenant binds, the quota's status shows its usage, and a
restarted operator continues from the usage in the status."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from typing import Any

import pytest
from armnet_core.api import API_VERSION, CELLQUOTAS, GROUP, VERSION
from armnet_core.times import micro_time

from tests.integration.client_bed import Tenant
from tests.integration.operator_bed import Bed, running_operator

pytestmark = pytest.mark.integration


def quota(bed: Bed, name: str, namespace: str, nominal: int) -> None:
    bed.apply({"apiVersion": API_VERSION, "kind": "CellQuota", "metadata": {"name": name},
               "spec": {"namespace": namespace, "embodiment": bed.embodiment, "nominalCells": nominal}})


def quota_status(bed: Bed, name: str) -> dict[str, Any]:
    return dict(bed.api.get_cluster_custom_object(GROUP, VERSION, CELLQUOTAS, name).get("status") or {})


def test_a_tenant_at_its_quota_waits_while_another_binds_and_usage_survives_a_restart(
        k8s: Any, namespace: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    other = k8s.create_namespace("fairshare-b")
    bed, bed_b = Bed(k8s, namespace), Bed(k8s, other)
    bed_b.embodiment = bed.embodiment
    qa, qb = f"a-{namespace}", f"b-{namespace}"
    try:
        quota(bed, qa, namespace, 1)
        quota(bed, qb, other, 1)
        bed.cell("c1")
        bed.cell("c2")
        settings = {"namespaces": (namespace, other), "quota_refresh": 0.5}
        with running_operator(k8s, namespace, monkeypatch, **settings):
            bed.job("a1")
            bed.wait_job("a1", phase="dispatched")
            bed.job("a2")
            body = bed.wait_job("a2", phase="queued", queuedReason="QuotaExhausted")
            assert qa in bed.condition(body, "Queued")["message"]
            bed_b.job("b1")
            bed_b.wait_job("b1", phase="dispatched")
            bed.wait("the quota's status with usage", lambda: (s := quota_status(bed, qa)).get("cellsInUse") == 1
                     and s.get("waitingJobs") == 1 and s["usage"]["decayedCellSeconds"] > 0)
        # The tenant's own view (KopfRunner swaps sys.stdout while it runs: asked once it stopped).
        capsys.readouterr()
        assert Tenant(k8s, namespace).cli("quota", "-o", "json") == 0
        standing = json.loads(capsys.readouterr().out)["items"]
        assert [(q["name"], q["cellsInUse"], q["waitingJobs"]) for q in standing] == [(qa, 1, 1)]  # not qb's tenant
        assert standing[0]["decayedUsageCellHours"] > 0
        planted = micro_time(datetime.now(UTC))
        bed.api.patch_cluster_custom_object_status(GROUP, VERSION, CELLQUOTAS, qa, {"status": {"usage": {
            "decayedCellSeconds": 100000, "updatedAt": planted}}})
        with running_operator(k8s, namespace, monkeypatch, **settings):
            usage = bed.wait("usage written again after the restart", lambda: (
                u := quota_status(bed, qa)["usage"])["updatedAt"] > planted and u)
            assert usage["decayedCellSeconds"] >= 99000  # read back, not restarted from zero
            assert bed.wait_job("a2", phase="queued")["status"]["queuedReason"] == "QuotaExhausted"
        header = k8s.kubectl("get", "cellquota", qa).stdout.splitlines()[0].split()
        assert {"TENANT", "NOMINAL", "INUSE", "WAITING"} <= set(header)
    finally:
        bed.close()
        bed_b.close()
        for name in (qa, qb):
            k8s.kubectl("delete", "cellquota", name, "--ignore-not-found", "--wait=false", check=False)
        k8s.delete_namespace(other)


def test_a_quota_the_operator_ignores_says_why_in_a_warning_event_on_it(
        k8s: Any, namespace: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A second CellQuota for the same scope is valid to the schema but ignored: `kubectl describe
    cellquota` shows why (an Event on it, once), not only the operator's log."""
    bed = Bed(k8s, namespace)
    kept, duplicate = f"a-{namespace}", f"z-{namespace}"
    try:
        quota(bed, kept, namespace, 1)
        quota(bed, duplicate, namespace, 5)
        with running_operator(k8s, namespace, monkeypatch, namespaces=(namespace,), quota_refresh=0.5):
            bed.wait("the duplicate's status", lambda: "ignored" in quota_status(bed, duplicate).get("message", ""))
            uid = bed.api.get_cluster_custom_object(GROUP, VERSION, CELLQUOTAS, duplicate)["metadata"]["uid"]

            def events() -> list[dict[str, Any]]:
                return [e for e in bed.core.list_namespaced_event(
                    "default", field_selector=f"involvedObject.kind=CellQuota,involvedObject.name={duplicate}",
                ).to_dict()["items"]]

            found = bed.wait("a QuotaIgnored event", lambda: events())
            assert [(e["type"], e["reason"], e["involved_object"]["uid"]) for e in found] == [
                ("Warning", "QuotaIgnored", uid)]
            assert kept in found[0]["message"] and "delete one of them" in found[0]["message"]
        described = k8s.kubectl("describe", "cellquota", duplicate).stdout
        assert "QuotaIgnored" in described
    finally:
        bed.close()
        for name in (kept, duplicate):
            k8s.kubectl("delete", "cellquota", name, "--ignore-not-found", "--wait=false", check=False)
