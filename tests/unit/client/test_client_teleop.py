"""Teleop's pure part: keys to recording events, the simulated leader, subjects and payloads."""

from __future__ import annotations

import json

import pytest
from armnet_client.teleop import (
    action_payload,
    event_payload,
    events_of_keys,
    simulated_action,
    teleop_subject,
)

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(("keys", "events"), [
    (b"\x1b[C", ["next_episode"]),
    (b"\x1b[D", ["rerecord_episode"]),
    (b"\x1b", ["stop_recording"]),
    (b"\x1b[C\x1b[C\x1b[D", ["next_episode", "next_episode", "rerecord_episode"]),
    (b"\x1b[A\x1b[B", []),
    (b"abc q", []),
])
def test_arrow_keys_and_esc_are_lerobots_recording_shortcuts(keys: bytes, events: list[str]) -> None:
    assert events_of_keys(keys) == events


def test_the_simulated_leader_names_the_so101_joints_like_lerobot() -> None:
    assert set(simulated_action(0.0)) == {"shoulder_pan.pos", "shoulder_lift.pos", "elbow_flex.pos",
                                          "wrist_flex.pos", "wrist_roll.pos", "gripper.pos"}


def test_the_simulated_leader_moves_by_small_steps_at_30_hz() -> None:
    samples = [simulated_action(i / 30) for i in range(300)]

    steps = [abs(a[k] - b[k]) for a, b in zip(samples, samples[1:], strict=False) for k in a]
    assert 0 < max(steps) < 1.0
    assert len({s["shoulder_pan.pos"] for s in samples}) > 100


def test_payloads_match_the_agent_contract() -> None:
    assert json.loads(action_payload({"gripper.pos": 50})) == {"action": {"gripper.pos": 50.0}}
    assert json.loads(event_payload("next_episode")) == {"event": "next_episode"}


def test_subjects_are_per_namespace_and_job_and_refuse_wildcards() -> None:
    assert teleop_subject("team-a", "uid", "action") == "teleop.team-a.uid.action"
    with pytest.raises(ValueError):
        teleop_subject("team-a", "*", "event")
    with pytest.raises(ValueError):
        teleop_subject("team-a", "uid", "stdout")
