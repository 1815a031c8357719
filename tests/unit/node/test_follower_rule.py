"""Which jobs the agent watches for a following client, for how long, and what the cancel says."""

from __future__ import annotations

import pytest
from armnet_core.api import FOLLOWER_TIMEOUT_ANNOTATION
from armnet_node.follower_rule import (
    DEFAULT_WINDOW_S,
    MAX_WINDOW_S,
    MIN_WINDOW_S,
    FollowerClock,
    follower_window,
    heartbeat_subject,
    lost_follower_message,
)
from armnet_node.model import parse_job

pytestmark = pytest.mark.unit


def test_a_job_without_the_annotation_is_not_watched_even_when_not_detached() -> None:
    assert follower_window({}, detach=False) is None


def test_a_detached_job_is_never_watched_whatever_its_annotations() -> None:
    assert follower_window({FOLLOWER_TIMEOUT_ANNOTATION: "30"}, detach=True) is None


def test_the_annotation_value_is_the_window_in_seconds() -> None:
    assert follower_window({FOLLOWER_TIMEOUT_ANNOTATION: "12.5"}, detach=False) == 12.5


@pytest.mark.parametrize("value", ["soon", "", "nan", "inf"])
def test_a_window_that_is_not_a_finite_number_falls_back_to_the_default(value: str) -> None:
    assert follower_window({FOLLOWER_TIMEOUT_ANNOTATION: value}, detach=False) == DEFAULT_WINDOW_S


@pytest.mark.parametrize(("value", "window"), [("0", MIN_WINDOW_S), ("-3", MIN_WINDOW_S), ("1e9", MAX_WINDOW_S)])
def test_the_window_is_clamped_so_a_tenant_cannot_set_a_hair_trigger_or_forever(value: str, window: float) -> None:
    assert follower_window({FOLLOWER_TIMEOUT_ANNOTATION: value}, detach=False) == window


def test_the_parsed_job_carries_its_window() -> None:
    obj = {"metadata": {"name": "j", "namespace": "team-a", "uid": "u1",
                        "annotations": {FOLLOWER_TIMEOUT_ANNOTATION: "8"}},
           "spec": {"image": "localhost/x:dev", "embodiment": "lerobot/so-101", "detach": False}}
    assert parse_job(obj).follower_window_s == 8.0
    obj["spec"]["detach"] = True
    assert parse_job(obj).follower_window_s is None


def test_the_heartbeat_subject_names_namespace_and_job_id() -> None:
    assert heartbeat_subject("team-a", "0d5e") == "clients.team-a.0d5e.heartbeat"


@pytest.mark.parametrize("token", ["a.b", "*", ">", "", "a b"])
def test_a_token_that_would_widen_the_subject_is_refused(token: str) -> None:
    with pytest.raises(ValueError, match="NATS subject token"):
        heartbeat_subject(token, "uid")


def test_the_clock_expires_only_after_a_whole_window_of_silence() -> None:
    clock = FollowerClock(10.0, now=100.0)
    assert not clock.expired(110.0)
    assert clock.expired(110.5)


def test_a_beat_restarts_the_window() -> None:
    clock = FollowerClock(10.0, now=100.0)
    clock.beat(108.0)
    assert not clock.expired(117.0)
    assert clock.expired(118.5)


def test_silence_while_the_agent_cannot_hear_beats_does_not_count() -> None:
    clock = FollowerClock(10.0, now=100.0)
    clock.pause(140.0)  # the agent's NATS link was down until now
    assert not clock.expired(145.0)


def test_a_late_delivered_old_beat_never_moves_the_clock_back() -> None:
    clock = FollowerClock(10.0, now=100.0)
    clock.beat(105.0)
    clock.beat(101.0)
    assert clock.silence(106.0) == 1.0


def test_the_cancel_message_says_why_and_how_to_keep_a_job_running() -> None:
    message = lost_follower_message(30.0, 31.2)
    assert "no heartbeat for 31.2 s (window 30 s)" in message
    assert "detach: true" in message and "--detach" in message
