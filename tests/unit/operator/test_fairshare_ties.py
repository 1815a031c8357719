"""Fair share: the next cell goes to the tenant with the lowest weighted, decayed usage; ties keep today's order."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_operator.quota import FairSharing
from fairshare_helpers import bound, cells, plan
from operator_builders import a_cell, a_job, a_quota, used

pytestmark = pytest.mark.unit

QUOTAS = [a_quota("team-a").nominal(5).build(), a_quota("team-b").nominal(5).build()]


def test_the_next_cell_goes_to_the_tenant_with_the_lowest_usage():
    heavy = a_job().named("a", "team-a").submitted_ago(900).queued()
    light = a_job().named("b", "team-b").submitted_ago(1).queued()
    usage = {"team-a-so101": used(1000), "team-b-so101": used(10)}
    assert bound(plan([heavy, light], cells(1), QUOTAS, usage)) == {"team-b/b": "c0"}


def test_usage_is_divided_by_the_weight():
    quotas = [a_quota("team-a").nominal(5).weighing(4).build(), a_quota("team-b").nominal(5).build()]
    weighty = a_job().named("a", "team-a").submitted_ago(1).queued()
    other = a_job().named("b", "team-b").submitted_ago(900).queued()
    usage = {"team-a-so101": used(1000), "team-b-so101": used(500)}
    assert bound(plan([weighty, other], cells(1), quotas, usage)) == {"team-a/a": "c0"}


def test_equal_usage_goes_to_the_higher_priority_then_the_earlier_job():
    early = a_job().named("a", "team-a").submitted_ago(900).queued()
    urgent = a_job().named("b", "team-b").with_priority(3).submitted_ago(1).queued()
    late = a_job().named("c", "team-b").submitted_ago(1).queued()
    assert bound(plan([early, late], cells(1), QUOTAS)) == {"team-a/a": "c0"}
    assert bound(plan([early, urgent], cells(1), QUOTAS)) == {"team-b/b": "c0"}


def test_within_a_tenant_priority_goes_first_then_first_come():
    old = a_job().named("old", "team-a").submitted_ago(900).queued()
    new = a_job().named("new", "team-a").submitted_ago(100).queued()
    urgent = a_job().named("urgent", "team-a").with_priority(5).submitted_ago(1).queued()
    result = plan([new, old, urgent], cells(2), QUOTAS, {"team-a-so101": used(0)})
    assert bound(result) == {"team-a/urgent": "c0", "team-a/old": "c1"}


def test_tenants_without_history_take_free_cells_in_turns():
    burst = [a_job().named(f"a{i}", "team-a").submitted_ago(900 - i).queued() for i in range(4)]
    later = [a_job().named(f"b{i}", "team-b").submitted_ago(10 - i).queued() for i in range(4)]
    result = plan([*burst, *later], cells(4), QUOTAS)
    assert set(bound(result)) == {"team-a/a0", "team-a/a1", "team-b/b0", "team-b/b1"}


def test_cells_held_now_count_against_a_tenant():
    holder = a_job().named("run", "team-a").running_on("busy")
    busy = a_cell().named("busy").claimed_by(holder).ready()
    first = a_job().named("a", "team-a").submitted_ago(900).queued()
    second = a_job().named("b", "team-b").submitted_ago(1).queued()
    assert bound(plan([holder, first, second], [busy, *cells(1)], QUOTAS)) == {"team-b/b": "c0"}


def test_with_no_entry_penalty_a_tenant_without_history_may_take_every_free_cell():
    burst = [a_job().named(f"a{i}", "team-a").submitted_ago(900 - i).queued() for i in range(2)]
    other = a_job().named("b", "team-b").submitted_ago(1).queued()
    sharing = FairSharing(entry_penalty=timedelta(0))
    assert set(bound(plan([*burst, other], cells(2), QUOTAS, sharing=sharing))) == {"team-a/a0", "team-a/a1"}


def test_without_quotas_the_order_is_priority_then_first_come_across_namespaces():
    burst = [a_job().named(f"a{i}", "team-a").submitted_ago(900 - i).queued() for i in range(2)]
    other = a_job().named("b", "team-b").submitted_ago(1).queued()
    result = plan([*burst, other], cells(2))
    assert set(bound(result)) == {"team-a/a0", "team-a/a1"}
    assert result.queued["team-b/b"].position == 1
