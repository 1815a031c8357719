"""The CellQuota CRD on the real API server: it is cluster-scoped, defaults the weight, rejects bad values readably."""

from __future__ import annotations

import json
import uuid
from typing import Any

import pytest
import yaml

pytestmark = pytest.mark.integration


def quota(**spec: Any) -> dict[str, Any]:
    body = {"namespace": "team-a", "embodiment": "lerobot/so-101", "nominalCells": 2, **spec}
    return {"apiVersion": "armnet.io/v1alpha1", "kind": "CellQuota",
            "metadata": {"name": f"q-{uuid.uuid4().hex[:6]}"}, "spec": body}


def test_a_quota_is_cluster_scoped_defaults_its_weight_and_prints_its_columns(k8s: Any) -> None:
    doc = quota(cohort="lab", borrowingLimit=1)
    name = doc["metadata"]["name"]
    k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(doc))
    try:
        stored = json.loads(k8s.kubectl("get", "cellquota", name, "-o", "json").stdout)
        lines = k8s.kubectl("get", "cquota", name).stdout.splitlines()
    finally:
        k8s.kubectl("delete", "cellquota", name, "--wait=false")
    assert "namespace" not in stored["metadata"] and stored["spec"]["weight"] == 1
    assert lines[0].split() == ["NAME", "TENANT", "EMBODIMENT", "TASK", "NOMINAL", "BORROW", "WEIGHT",
                                "COHORT", "INUSE", "WAITING", "AGE"]
    assert lines[1].split()[:6] == [name, "team-a", "lerobot/so-101", "2", "1", "1"]  # TASK blank


@pytest.mark.parametrize(("spec", "says"), [
    ({"nominalCells": -1}, "spec.nominalCells: Invalid value: -1"),
    ({"weight": 0}, "spec.weight: Invalid value: 0"),
    ({"namespace": "Team_A"}, "spec.namespace: Invalid value"),
    ({"period": "Fortnight", "creditsCellHours": 1}, 'spec.period: Unsupported value: "Fortnight"'),
    ({"creditsCellHours": 5}, "creditsCellHours and period go together"),
    ({"borrowingLimit": 2}, "borrowingLimit needs a cohort to borrow from"),
])
def test_bad_values_are_rejected_with_a_readable_message(k8s: Any, spec: dict[str, Any], says: str) -> None:
    result = k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(quota(**spec)), check=False)
    assert result.returncode != 0 and says in result.stderr, result.stderr
