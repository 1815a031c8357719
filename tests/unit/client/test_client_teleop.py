"""Teleop's pure part: keys to recording events, the simulated leader, subjects and payloads,
and the follower's state as the job's Rerun packets report it, drawn as two live lines."""

from __future__ import annotations

import json

import pytest
from armnet_client.teleop import (
    FollowerView,
    action_payload,
    event_payload,
    events_of_keys,
    follower_state,
    redraw,
    rerun_subject,
    simulated_action,
    status_lines,
    teleop_subject,
)
from armnet_runtime.rerun import ENCODING_JPEG, Entry, ImageData, Packet

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


def test_the_follower_state_arrives_on_the_jobs_rerun_subject() -> None:
    assert rerun_subject("team-a", "uid") == "logs.team-a.uid.rerun"
    with pytest.raises(ValueError):
        rerun_subject("team-a", "u.*")


def test_the_follower_state_is_the_packets_observation_scalars_in_the_jobs_order() -> None:
    packet = Packet("uid", 0, 7, 0, (
        Entry("observation.shoulder_pan.pos", scalar=12.5),
        Entry("action.shoulder_pan.pos", scalar=13.0),
        Entry("observation.front", image=ImageData(2, 1, 3, ENCODING_JPEG, b"\xff\xd8")),
        Entry("observation.gripper.pos", scalar=40.0),
    ))

    assert follower_state(packet) == {"shoulder_pan.pos": 12.5, "gripper.pos": 40.0}
    assert list(follower_state(packet) or {}) == ["shoulder_pan.pos", "gripper.pos"]


def test_a_packet_without_observation_scalars_leaves_the_last_state_standing() -> None:
    assert follower_state(Packet("uid", 0, 1, 0, (Entry("action.gripper.pos", scalar=1.0),))) is None


def test_the_status_shows_what_was_sent_and_the_followers_joints_with_their_age() -> None:
    follower = FollowerView({"shoulder_pan.pos": 12.54, "gripper.pos": -3.0}, age_s=0.3)

    assert status_lines("sim", 42, "next_episode", follower) == [
        "simulated leader: 42 actions sent, last event next_episode",
        "follower (0.3 s ago): shoulder_pan 12.5  gripper -3.0",
    ]


def test_a_jobs_joint_names_reach_the_terminal_without_escapes_or_wide_characters() -> None:
    follower = FollowerView({"\x1b]0;pwned\x07\x1b[2Jpan.pos": 1.0, "\u5de6\u8155.pos": 2.0, "x" * 500: 3.0})

    line = status_lines("sim", 1, None, follower)[1]

    assert all(" " <= c <= "~" for c in line)
    assert "?]0;pwned??[2Jpan 1.0" in line and "?? 2.0" in line
    assert len(line) < 200  # each name cut to 64 characters


def test_before_any_state_the_status_says_how_the_job_reports_it() -> None:
    lines = status_lines("/dev/ttyACM1", 0, None, FollowerView())

    assert lines[0] == "leader arm on /dev/ttyACM1: 0 actions sent, last event -"
    assert "ctx.log_rerun_data(observation=" in lines[1]


def test_the_first_draw_clears_each_line_and_a_redraw_goes_back_up_over_them() -> None:
    assert redraw(["a", "b"], 0, 80) == "\r\x1b[2Ka\n\x1b[2Kb"
    assert redraw(["a", "b"], 2, 80) == "\x1b[1A\r\x1b[2Ka\n\x1b[2Kb"


def test_lines_are_cut_to_the_terminal_width_so_none_wraps() -> None:
    assert redraw(["x" * 100], 0, 10) == "\r\x1b[2K" + "x" * 9
