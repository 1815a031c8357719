"""Boundaries: parsing bodies into models, patches with preconditions, settings, the Lease decision."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_core.api import RELEASE_CELL_FINALIZER
from armnet_operator.errors import PermanentError
from armnet_operator.leader import LeaseMove, LeaseSeen, LeaseView, decide_lease, observe
from armnet_operator.model import CellPhase, JobPhase, QueuedReason
from armnet_operator.parsing import parse_cell, parse_job
from armnet_operator.patches import (
    Target,
    add_finalizer,
    bind_job,
    claim_cell,
    release_cell,
    set_finalizer,
)
from armnet_operator.scheduling import QueueEntry
from armnet_operator.settings import load_settings
from operator_builders import NOW, a_cell, a_job, ago

pytestmark = pytest.mark.unit


def test_a_robotjob_body_parses_into_the_model() -> None:
    job = parse_job({
        "metadata": {"name": "j", "namespace": "t", "uid": "u", "resourceVersion": "7",
                     "creationTimestamp": "2026-01-01T12:00:00Z", "finalizers": [RELEASE_CELL_FINALIZER]},
        "spec": {"embodiment": "lerobot/so-101", "task": "fold", "priority": 3, "cancel": False},
        "status": {"phase": "dispatched", "cellName": "c", "conditions": [
            {"type": "Bound", "status": "True", "lastTransitionTime": "2026-01-01T12:00:05Z"}]},
    })
    assert (job.key, job.phase, job.cell_name, job.priority, job.has_finalizer) == ("t/j", JobPhase.DISPATCHED, "c", 3, True)
    assert job.bound_at is not None and job.bound_at.second == 5


def test_a_cell_body_parses_failing_health_conditions() -> None:
    cell = parse_cell({
        "metadata": {"name": "c", "resourceVersion": "3"},
        "spec": {"embodiment": "lerobot/so-101", "nodeName": "h"},
        "status": {"lastHeartbeatTime": "2026-01-01T12:00:00Z", "conditions": [
            {"type": "InterlockClear", "status": "False"}, {"type": "Custom", "status": "False"}]},
    })
    assert cell.failing_conditions == ("InterlockClear",)


def test_a_cell_whose_agent_has_no_nats_still_takes_jobs() -> None:
    """StreamsConnected=False tells the cell operator why the buttons do nothing; jobs run without NATS."""
    cell = parse_cell({
        "metadata": {"name": "c", "resourceVersion": "3"},
        "spec": {"embodiment": "lerobot/so-101", "nodeName": "h"},
        "status": {"lastHeartbeatTime": "2026-01-01T12:00:00Z", "conditions": [
            {"type": "StreamsConnected", "status": "False", "reason": "NatsNotConfigured"}]},
    })
    assert cell.failing_conditions == ()


def test_a_claim_carries_the_observed_resource_version() -> None:
    patch = claim_cell(a_cell().named("c").ready(), a_job().named("j").queued(), NOW)
    assert patch.body["metadata"] == {"resourceVersion": "1"}
    assert patch.body["status"]["currentJob"] == "tenant-a/j"
    assert patch.body["status"]["phase"] == CellPhase.BUSY


def test_binding_sets_phase_cell_job_id_and_the_bound_condition() -> None:
    job = a_job().named("j").queued()
    status = bind_job(job, a_cell().named("c").ready(), NOW).body["status"]
    assert (status["phase"], status["cellName"], status["jobId"]) == ("dispatched", "c", job.uid)
    assert [c["type"] for c in status["conditions"]] == ["Bound", "Queued"]


def test_releasing_deletes_the_claim_fields() -> None:
    status = release_cell(a_cell().claimed_by("t/j").ready(), CellPhase.READY).body["status"]
    assert status == {"currentJob": None, "claimedAt": None, "phase": "Ready", "message": None}


def test_finalizer_patches_keep_other_finalizers() -> None:
    job = a_job()._with(finalizers=("other.io/keep", RELEASE_CELL_FINALIZER)).queued()
    assert set_finalizer(job, False).body["metadata"]["finalizers"] == ["other.io/keep"]


def test_adding_the_finalizer_appends_to_the_list_as_seen_with_a_json_patch_and_no_resource_version() -> None:
    job = a_job().named("j")._with(finalizers=("other.io/keep",)).queued()
    patch = add_finalizer(job)
    assert (patch.target, patch.name, patch.body) == (Target.JOB, "j", {})
    assert patch.operations == (
        {"op": "test", "path": "/metadata/finalizers", "value": ["other.io/keep"]},
        {"op": "add", "path": "/metadata/finalizers/-", "value": RELEASE_CELL_FINALIZER},
    )


def test_adding_the_first_finalizer_tests_that_the_list_is_still_absent() -> None:
    patch = add_finalizer(a_job().without_finalizer().queued())
    assert patch.body == {}
    assert patch.operations == (
        {"op": "test", "path": "/metadata/finalizers", "value": None},
        {"op": "add", "path": "/metadata/finalizers", "value": [RELEASE_CELL_FINALIZER]},
    )


def test_metrics_count_jobs_queue_depth_cells_and_bind_latency() -> None:
    from armnet_operator.metrics import Metrics
    from armnet_operator.reconcile import Outcome

    metrics = Metrics()
    bound = a_job().submitted_ago(3).queued()
    waiting = a_job().with_task("fold").queued()
    outcome = Outcome(bound=[(bound, a_cell().ready())], conflicts=2,
                      queue={waiting.key: QueueEntry(QueuedReason.ALL_CELLS_BUSY, 1, "")})
    metrics.observe(outcome, [bound, waiting], [a_cell().ready()], NOW)
    sample = metrics.registry.get_sample_value
    assert sample("armnet_robotjobs", {"phase": "queued"}) == 2
    assert sample("armnet_queue_depth", {"embodiment": "lerobot/so-101", "task": "fold"}) == 1
    assert sample("armnet_cells", {"phase": "Ready"}) == 1
    assert sample("armnet_binding_conflicts_total") == 2
    assert sample("armnet_bind_latency_seconds_sum") == 3.0


def test_settings_come_from_env_and_flags_override_them() -> None:
    env = {"ARMNET_OPERATOR_HEARTBEAT_TIMEOUT": "12", "ARMNET_OPERATOR_NAMESPACES": "a, b"}
    settings = load_settings({"heartbeat_timeout": "7"}, environ=env)
    assert settings.heartbeat_timeout == 7 and settings.namespaces == ("a", "b")
    assert settings.timing.heartbeat_timeout == timedelta(seconds=7)
    assert load_settings({}, environ={"ARMNET_OPERATOR_DEFAULT_TTL": "none"}).timing.default_ttl is None


def test_bad_settings_name_the_variable_and_the_flag() -> None:
    with pytest.raises(PermanentError, match="ARMNET_OPERATOR_HEARTBEAT_TIMEOUT .--heartbeat-timeout."):
        load_settings({}, environ={"ARMNET_OPERATOR_HEARTBEAT_TIMEOUT": "-1"})


DURATION = timedelta(seconds=15)


@pytest.mark.parametrize(("lease", "move"), [
    (None, LeaseMove.ACQUIRE),
    (LeaseView("me", ago(100), DURATION), LeaseMove.RENEW),
    (LeaseView("other", ago(100), DURATION), LeaseMove.FOLLOW),  # just seen: its age on the holder's clock is no evidence
    (LeaseView("", None, DURATION), LeaseMove.ACQUIRE),
])
def test_the_lease_is_taken_only_when_free_and_followed_when_first_seen(lease: LeaseView | None, move: LeaseMove) -> None:
    seen = observe(None, lease, 1000.0) if lease is not None else None
    assert decide_lease(seen, "me", 1000.0) is move


def _holder_plays(skew: timedelta, renews_until: float, looks: list[float]) -> list[LeaseMove]:
    """The other replica renews every 5 s of the candidate's time up to ``renews_until``, stamping
    renewTime on its own clock (the candidate's wall clock + ``skew``); the candidate looks at ``looks``
    (its monotonic seconds, starting at 0) and says what it would do each time."""
    seen: LeaseSeen | None = None
    moves = []
    for t in looks:
        last_renewal = min(t, renews_until) // 5 * 5
        lease = LeaseView("other", NOW + skew + timedelta(seconds=last_renewal), DURATION, transitions=3, acquired=NOW + skew)
        seen = observe(seen, lease, t)
        moves.append(decide_lease(seen, "me", t))
    return moves


LOOKS = [0.0, 6.0, 12.0, 18.0, 24.0, 30.0, 36.0, 42.0, 48.0, 54.0, 60.0]
SKEWS = [timedelta(hours=1), timedelta(hours=-1), timedelta(0)]


@pytest.mark.parametrize("skew", SKEWS, ids=["holder-1h-ahead", "holder-1h-behind", "no-skew"])
def test_a_holder_that_keeps_renewing_is_never_taken_over_whatever_its_clock(skew: timedelta) -> None:
    assert set(_holder_plays(skew, renews_until=1e9, looks=LOOKS)) == {LeaseMove.FOLLOW}


@pytest.mark.parametrize("skew", SKEWS, ids=["holder-1h-ahead", "holder-1h-behind", "no-skew"])
def test_a_holder_that_stops_renewing_is_taken_over_a_lease_duration_after_the_last_change_seen(skew: timedelta) -> None:
    # Last renewal at 20 s; the candidate sees it at its look at 24 s, so the lease is its own from 24 + 15 = 39 s on.
    moves = _holder_plays(skew, renews_until=20.0, looks=LOOKS)
    assert moves == [LeaseMove.FOLLOW] * 7 + [LeaseMove.ACQUIRE] * 4


def test_expiry_is_exact_on_the_candidates_own_clock() -> None:
    seen = observe(None, LeaseView("other", NOW + timedelta(days=365), DURATION), 100.0)
    assert decide_lease(seen, "me", 115.0) is LeaseMove.FOLLOW
    assert decide_lease(seen, "me", 115.001) is LeaseMove.ACQUIRE
    assert observe(seen, LeaseView("other", NOW + timedelta(days=365), DURATION), 114.0) is seen  # unchanged: clock keeps running
    renewed = observe(seen, LeaseView("other", NOW - timedelta(days=365), DURATION), 114.0)  # any change restarts it
    assert decide_lease(renewed, "me", 120.0) is LeaseMove.FOLLOW


@pytest.mark.parametrize("skew", SKEWS, ids=["ours-1h-ahead", "ours-1h-behind", "no-skew"])
def test_our_own_lease_is_renewed_whenever_we_look(skew: timedelta) -> None:
    seen = observe(None, LeaseView("me", NOW + skew, DURATION), 0.0)
    assert [decide_lease(seen, "me", t) for t in (0.0, 14.0, 16.0, 3600.0)] == [LeaseMove.RENEW] * 4
