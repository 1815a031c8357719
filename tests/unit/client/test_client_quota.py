"""``armnet quota``: a CellQuota body as the tenant's standing, in a table and as JSON."""

from __future__ import annotations

from typing import Any

import pytest
from armnet_client.mapping import quota_view_of
from armnet_client.render import quota_document, quotas_table
from armnet_core.api import API_VERSION

pytestmark = pytest.mark.unit


def a_quota(name: str = "team-a-so101", **spec: Any) -> dict[str, Any]:
    status = spec.pop("status", {})
    return {"apiVersion": API_VERSION, "kind": "CellQuota", "metadata": {"name": name},
            "spec": {"namespace": "team-a", "embodiment": "lerobot/so-101", "nominalCells": 2, **spec},
            "status": status}


HOLDING = {"cellsInUse": 3, "borrowedCells": 1, "waitingJobs": 4,
           "usage": {"decayedCellSeconds": 9000, "periodCellSeconds": 12600, "periodStart": "2026-11-23T00:00:00Z"}}


def rows(text: str) -> list[list[str]]:
    return [line.split() for line in text.splitlines()]


def test_the_table_shows_the_share_what_the_tenant_holds_borrows_and_waits_for_and_its_credits() -> None:
    quota = quota_view_of(a_quota(cohort="lab", creditsCellHours=40, period="Week", status=HOLDING))
    header, row = rows(quotas_table([quota]))
    assert header == ["NAME", "TENANT", "EMBODIMENT", "TASK", "NOMINAL", "IN-USE", "BORROWED", "WAITING",
                      "CREDITS", "NOTE"]
    assert row == ["team-a-so101", "team-a", "lerobot/so-101", "<any>", "2", "3", "1", "4",
                   "3.5h/40.0h", "per", "Week", "-"]


def test_wide_adds_the_cohort_the_borrowing_limit_the_weight_and_the_decayed_usage() -> None:
    unlimited = quota_view_of(a_quota(cohort="lab", weight=2, status=HOLDING))
    limited = quota_view_of(a_quota("b", cohort="lab", borrowingLimit=1))
    alone = quota_view_of(a_quota("c"))
    table = rows(quotas_table([unlimited, limited, alone], wide=True))
    assert table[0][-4:] == ["COHORT", "BORROW-LIMIT", "WEIGHT", "USAGE"]
    assert [r[-4:] for r in table[1:]] == [["lab", "<idle>", "2", "2.5h"], ["lab", "1", "1", "0.0h"],
                                          ["-", "-", "1", "0.0h"]]


def test_a_quota_the_operator_ignores_says_why() -> None:
    quota = quota_view_of(a_quota(status={"message": "ignored: team-a-other already covers this scope"}))
    assert quotas_table([quota]).splitlines()[1].endswith("ignored: team-a-other already covers this scope")


def test_a_quota_that_cannot_be_read_is_listed_with_its_problem_not_an_error() -> None:
    """Stored before the schema, or with validation off: the tenant still sees that it exists."""
    quota = quota_view_of(a_quota("old", nominalCells=-3, borrowingLimit=2))
    assert (quota.name, quota.tenant) == ("old", "team-a")
    assert quota.problem is not None and "nominalCells" in quota.problem and "ignores it" in quota.problem
    assert rows(quotas_table([quota]))[1][:3] == ["old", "team-a", "?"]
    assert quota_document(quota)["problem"] == quota.problem


def test_the_json_shape() -> None:
    quota = quota_view_of(a_quota(task="fold", creditsCellHours=40, period="Week", status=HOLDING))
    assert quota_document(quota) == {
        "name": "team-a-so101", "tenant": "team-a", "embodiment": "lerobot/so-101", "task": "fold",
        "nominalCells": 2, "borrowingLimit": None, "weight": 1.0, "cohort": None,
        "cellsInUse": 3, "borrowedCells": 1, "waitingJobs": 4,
        "credits": {"cellHours": 40.0, "period": "Week", "usedCellHours": 3.5},
        "decayedUsageCellHours": 2.5, "message": None, "problem": None,
    }
