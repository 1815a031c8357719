"""The CellQuota boundary: good bodies become quotas, bad ones a readable error that names the fields."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from armnet_operator.errors import PermanentError
from armnet_operator.quota import CellQuota, QuotaPeriod, Usage
from armnet_operator.quota_parsing import parse_cell_quota, parse_usage, usage_status
from operator_builders import NOW

pytestmark = pytest.mark.unit

EXAMPLE = Path(__file__).resolve().parents[3] / "crds" / "examples" / "cellquota.yaml"


def body(**spec: object) -> dict[str, object]:
    return {"metadata": {"name": "q", "resourceVersion": "7"},
            "spec": {"namespace": "team-a", "embodiment": "lerobot/so-101", "nominalCells": 2, **spec}}


def test_the_example_manifest_parses_into_the_quotas_it_describes():
    a, b = (parse_cell_quota(doc) for doc in yaml.safe_load_all(EXAMPLE.read_text()))
    assert a == CellQuota("team-a-so101", "team-a", "lerobot/so-101", 2, weight=2.0, cohort="lab",
                          preempt_lower_priority=True)
    assert (b.borrowing_limit, b.credits_cell_hours, b.period) == (2, 40.0, QuotaPeriod.WEEK)


def test_the_weight_defaults_to_one_and_the_resource_version_is_kept():
    quota = parse_cell_quota(body())
    assert (quota.weight, quota.resource_version, quota.borrowing_limit) == (1.0, "7", None)


@pytest.mark.parametrize(("spec", "says"), [
    ({"nominalCells": -1}, "spec.nominalCells: Input should be greater than or equal to 0"),
    ({"weight": 0}, "spec.weight"),
    ({"namespace": "Team A"}, "spec.namespace"),
    ({"creditsCellHours": 5}, "creditsCellHours and period go together"),
    ({"borrowingLimit": 1}, "borrowingLimit needs a cohort"),
    ({"period": "Fortnight", "creditsCellHours": 1}, "spec.period"),
])
def test_a_malformed_quota_is_an_error_naming_the_quota_and_the_field(spec, says):
    with pytest.raises(PermanentError) as error:
        parse_cell_quota(body(**spec))
    assert "CellQuota 'q' was ignored until fixed" in str(error.value) and says in str(error.value)


def test_a_quota_without_a_spec_is_an_error_not_a_crash():
    with pytest.raises(PermanentError, match="CellQuota 'q' has no spec"):
        parse_cell_quota({"metadata": {"name": "q"}, "spec": "nonsense"})


def test_usage_round_trips_through_the_status():
    usage = Usage(123.5, 60.0, NOW, NOW)
    assert parse_usage({"status": {"usage": usage_status(usage)}}) == usage


@pytest.mark.parametrize("status", [None, {}, {"usage": "lots"}, {"usage": {"decayedCellSeconds": -5}},
                                    {"usage": {"updatedAt": "yesterday"}}])
def test_missing_or_unreadable_usage_reads_as_none_yet(status):
    assert parse_usage({"status": status}) == Usage()
