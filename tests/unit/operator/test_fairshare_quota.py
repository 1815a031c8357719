"""Quotas: a tenant holds at most its CellQuota's cells, and waiting for it never blocks anyone else."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_operator.fairshare import index_quotas
from armnet_operator.model import QueuedReason
from armnet_operator.quota import QuotaPeriod, Usage, period_start
from fairshare_helpers import bound, cells, plan
from operator_builders import BIMANUAL, NOW, a_cell, a_job, a_quota

pytestmark = pytest.mark.unit


def test_a_namespace_without_a_cellquota_is_not_rationed():
    jobs = [a_job().named(f"j{i}", "free-ns").queued() for i in range(3)]
    quota = a_quota("team-a").nominal(1).build()
    assert len(bound(plan(jobs, cells(3), [quota]))) == 3


def test_a_tenant_at_its_nominal_share_waits_with_a_reason_naming_the_quota():
    running = a_job().named("run", "team-a").running_on("c0")
    waiting = a_job().named("wait", "team-a").queued()
    result = plan([running, waiting], [a_cell().named("c0").claimed_by(running).ready(), *cells(1, "f")],
                  [a_quota("team-a").named("lab-a").nominal(1).build()])
    assert bound(result) == {}
    entry = result.queued["team-a/wait"]
    assert entry.reason is QueuedReason.QUOTA_EXHAUSTED
    assert "CellQuota 'lab-a' gives 1 nominal" in entry.message and "1 are in use" in entry.message


def test_a_tenant_beyond_its_quota_never_blocks_another_tenant():
    urgent = [a_job().named(f"a{i}", "team-a").with_priority(9).submitted_ago(900).queued() for i in range(3)]
    other = a_job().named("b0", "team-b").submitted_ago(1).queued()
    result = plan([*urgent, other], cells(2), [a_quota("team-a").nominal(1).build()])
    assert set(bound(result)) == {"team-a/a0", "team-b/b0"}
    assert {result.queued[k].reason for k in ("team-a/a1", "team-a/a2")} == {QueuedReason.QUOTA_EXHAUSTED}


def test_a_job_no_quota_of_its_rationed_namespace_covers_waits():
    job = a_job().named("bi", "team-a").with_embodiment(BIMANUAL).queued()
    result = plan([job], [a_cell().with_embodiment(BIMANUAL).ready()], [a_quota("team-a").build()])
    assert bound(result) == {}
    assert result.queued[job.key].reason is QueuedReason.QUOTA_EXHAUSTED
    assert "no CellQuota of namespace 'team-a' covers embodiment 'lerobot/bimanual_so101'" in result.queued[job.key].message


def test_a_task_quota_governs_its_task_and_the_general_quota_the_other_jobs():
    fold = [a_job().named(f"fold{i}", "team-a").with_task("fold").queued() for i in range(2)]
    plain = [a_job().named(f"any{i}", "team-a").queued() for i in range(2)]
    quotas = [a_quota("team-a").named("fold").for_task("fold").nominal(2).build(),
              a_quota("team-a").named("general").nominal(1).build()]
    fold_cells = [a_cell().named(f"fc{i}").with_task("fold").ready() for i in range(2)]
    result = plan([*fold, *plain], [*fold_cells, *cells(2)], quotas)
    assert set(bound(result)) == {"team-a/fold0", "team-a/fold1", "team-a/any0"}
    assert "'general'" in result.queued["team-a/any1"].message


def test_credits_used_up_this_period_hold_the_tenant_until_the_next_period():
    quota = a_quota("team-a").named("weekly").nominal(4).with_credits(1.0, QuotaPeriod.WEEK).build()
    spent = Usage(period_cell_seconds=3600, period_start=period_start(NOW, QuotaPeriod.WEEK), updated_at=NOW)
    job = a_job().named("j", "team-a").queued()
    result = plan([job], cells(1), [quota], {"weekly": spent})
    assert result.queued[job.key].reason is QueuedReason.QUOTA_EXHAUSTED
    assert "1 cell-hour(s) of this week are used up; new credits at 2026-01-05T00:00Z" in result.queued[job.key].message


def test_credits_spent_in_a_past_period_do_not_count():
    quota = a_quota("team-a").named("daily").nominal(4).with_credits(1.0, QuotaPeriod.DAY).build()
    yesterday = Usage(period_cell_seconds=9000, period_start=period_start(NOW - timedelta(days=1), QuotaPeriod.DAY),
                      updated_at=NOW - timedelta(days=1))
    job = a_job().named("j", "team-a").queued()
    assert bound(plan([job], cells(1), [quota], {"daily": yesterday})) == {job.key: "c0"}


def test_a_missing_cell_is_the_reason_before_the_quota():
    job = a_job().named("j", "team-a").with_embodiment("acme/arm").queued()
    quota = a_quota("team-a").for_embodiment("acme/arm").nominal(0).build()
    assert plan([job], cells(1), [quota]).queued[job.key].reason is QueuedReason.NO_CELL_FOR_EMBODIMENT


def test_jobs_waiting_on_their_quota_queue_behind_jobs_waiting_for_a_cell():
    held = a_job().named("old", "team-a").submitted_ago(900).queued()
    later = a_job().named("new", "team-b").submitted_ago(1).queued()
    running = a_job().named("run", "team-a").running_on("c0")
    result = plan([held, later, running], [a_cell().named("c0").claimed_by(running).ready()],
                  [a_quota("team-a").nominal(1).build()])
    assert (result.queued[later.key].position, result.queued[held.key].position) == (1, 2)


def test_two_quotas_for_the_same_tenant_and_scope_are_reported_and_the_first_by_name_counts():
    first, second = a_quota("team-a").named("a-1").build(), a_quota("team-a").named("a-2").build()
    kept, problems = index_quotas([second, first])
    assert list(kept) == ["a-1"]
    assert problems == ["CellQuota 'a-2' is ignored: 'a-1' already covers namespace 'team-a', "
                        "embodiment 'lerobot/so-101'; delete one of them"]
