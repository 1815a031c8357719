"""What the FMS keeps of reset notices: the agent repeats a notice while its reset waits, and may be heard late."""

from __future__ import annotations

import pytest
from armnet_fms.local import LocalFleet
from armnet_fms.state import ENDED_REQUESTS_KEPT, REPEAT_GRACE_S, FleetState

from tests.unit.fms.fms_builders import NOW, a_cell, a_job, a_notice

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = NOW

    def __call__(self) -> float:
        return self.now


def a_state(clock: Clock) -> FleetState:
    source = LocalFleet("so101-a", "job-uid-1", reset_timeout_s=30, rollout=lambda: None, on_stop=lambda: None)
    state = FleetState(kube=source, clock=clock)
    state.cells = [a_cell(reset_timeout=30)]
    return state


def a_request(at: str = "2027-01-15T07:59:59+00:00", elapsed: float = 0.0) -> dict[str, object]:
    return {**a_notice(at=at), "request": f"job-uid-1@{at}", "elapsed": elapsed}


def test_a_repeated_notice_keeps_the_deadline_first_reckoned() -> None:
    clock = Clock()
    state = a_state(clock)
    state.on_reset_requested("so101-a", a_request())
    clock.now += 10
    state.on_reset_requested("so101-a", a_request())  # a repeat whose elapsed was lost would add 10 s
    assert state.pending["so101-a"].seconds_left(clock.now) == 20


def test_the_first_notice_heard_may_be_a_repeat_and_shows_the_time_really_left() -> None:
    clock = Clock()
    state = a_state(clock)
    state.on_reset_requested("so101-a", a_request(elapsed=8))
    assert state.pending["so101-a"].seconds_left(clock.now) == 22


def test_a_repeat_in_flight_at_the_confirmation_does_not_bring_its_button_back() -> None:
    clock = Clock()
    state = a_state(clock)
    state.on_reset_requested("so101-a", a_request())
    state.clear_reset("so101-a", "job-uid-1@2027-01-15T07:59:59+00:00")
    clock.now += 2
    state.on_reset_requested("so101-a", a_request(elapsed=2))  # sent before the click reached the job
    assert "so101-a" not in state.pending


def test_repeats_after_the_grace_mean_the_confirmation_was_lost_and_the_button_comes_back() -> None:
    clock = Clock()
    state = a_state(clock)
    state.on_reset_requested("so101-a", a_request())
    state.clear_reset("so101-a", "job-uid-1@2027-01-15T07:59:59+00:00")
    clock.now += REPEAT_GRACE_S + 1
    state.on_reset_requested("so101-a", a_request(elapsed=REPEAT_GRACE_S + 1))
    assert state.pending["so101-a"].seconds_left(clock.now) == 30 - REPEAT_GRACE_S - 1


def test_a_repeat_of_a_reset_past_its_deadline_stays_gone() -> None:
    clock = Clock()
    state = a_state(clock)
    state.on_reset_requested("so101-a", a_request())
    clock.now += 31
    state._forget_expired()
    state.on_reset_requested("so101-a", a_request(elapsed=2))
    assert "so101-a" not in state.pending


def test_a_later_wait_replaces_the_one_shown_and_the_earlier_one_cannot_return() -> None:
    clock = Clock()
    state = a_state(clock)
    state.on_reset_requested("so101-a", a_request(at="2027-01-15T07:59:00+00:00"))
    clock.now += 30
    state.on_reset_requested("so101-a", a_request(at="2027-01-15T07:59:30+00:00"))
    clock.now += 1
    state.on_reset_requested("so101-a", a_request(at="2027-01-15T07:59:00+00:00", elapsed=31))  # late repeat
    assert state.pending["so101-a"].request_id == "job-uid-1@2027-01-15T07:59:30+00:00"


def test_a_late_repeat_of_an_earlier_wait_never_shown_does_not_hide_the_wait_shown() -> None:
    clock = Clock()
    state = a_state(clock)
    state.on_reset_requested("so101-a", a_request(at="2027-01-15T07:59:30+00:00", elapsed=1))
    state.on_reset_requested("so101-a", a_request(at="2027-01-15T07:59:00+00:00", elapsed=20))
    assert state.pending["so101-a"].request_id == "job-uid-1@2027-01-15T07:59:30+00:00"


def test_a_later_notice_naming_a_job_the_cell_does_not_run_never_hides_the_running_jobs_prompt() -> None:
    clock = Clock()
    state = a_state(clock)
    state.jobs = [a_job()]  # the cell runs team-a/eval-1, uid job-uid-1
    state.on_reset_requested("so101-a", a_request())
    clock.now += 1
    forged = {**a_notice(job_id="other-uid", at="2027-01-15T08:00:00+00:00"), "request": "other-uid@x"}
    state.on_reset_requested("so101-a", forged)
    assert state.pending["so101-a"].request_id == "job-uid-1@2027-01-15T07:59:59+00:00"
    assert state.rows()[0].reset is not None


def test_the_next_jobs_first_wait_replaces_a_prompt_left_by_the_job_before() -> None:
    clock = Clock()
    state = a_state(clock)
    state.jobs = [a_job()]
    state.on_reset_requested("so101-a", a_request())
    clock.now += 5
    state.cells = [a_cell(job="team-a/eval-2")]  # the poll: the cell moved on to the next job
    state.jobs = [a_job(name="eval-2", job_id="job-uid-2")]
    state.on_reset_requested("so101-a", {**a_notice(job_id="job-uid-2", at="2027-01-15T08:00:04+00:00"),
                                         "request": "job-uid-2@2027-01-15T08:00:04+00:00"})
    assert state.pending["so101-a"].job_uid == "job-uid-2"


def test_a_notice_for_a_cell_the_fms_does_not_list_makes_no_button() -> None:
    state = a_state(Clock())
    state.on_reset_requested("forged-cell", a_request())
    assert state.pending == {}


def test_the_memory_of_ended_requests_is_bounded() -> None:
    clock = Clock()
    state = a_state(clock)
    for i in range(ENDED_REQUESTS_KEPT + 10):
        clock.now += 1
        state.on_reset_requested("so101-a", a_request(at=f"2027-01-15T07:59:59.{i:06d}+00:00"))
    assert len(state.ended_requests) == ENDED_REQUESTS_KEPT
