"""Condition helpers follow the Kubernetes conventions and report whether they changed."""

from __future__ import annotations

from datetime import timedelta

import pytest
from armnet_operator.conditions import is_true, remove_condition, set_condition
from operator_builders import NOW

pytestmark = pytest.mark.unit


def test_setting_a_new_condition_adds_it_with_the_transition_time():
    conditions: list[dict] = []
    assert set_condition(conditions, "Queued", True, "AllCellsBusy", "wait", NOW) is True
    assert conditions == [
        {"type": "Queued", "status": "True", "reason": "AllCellsBusy", "message": "wait",
         "lastTransitionTime": "2026-01-01T12:00:00Z"}
    ]


def test_setting_the_same_condition_again_changes_nothing():
    conditions: list[dict] = []
    set_condition(conditions, "Queued", True, "AllCellsBusy", "wait", NOW)
    assert set_condition(conditions, "Queued", True, "AllCellsBusy", "wait", NOW) is False


def test_a_new_reason_keeps_the_transition_time_while_status_is_unchanged():
    conditions: list[dict] = []
    set_condition(conditions, "Queued", True, "AllCellsBusy", "wait", NOW)
    later = NOW + timedelta(minutes=1)
    assert set_condition(conditions, "Queued", True, "AllCellsUnavailable", "x", later) is True
    assert conditions[0]["lastTransitionTime"] == "2026-01-01T12:00:00Z"


def test_flipping_status_moves_the_transition_time():
    conditions: list[dict] = []
    set_condition(conditions, "Bound", False, "Requeued", "", NOW)
    set_condition(conditions, "Bound", True, "ClaimedCell", "", NOW + timedelta(seconds=5))
    assert conditions[0]["lastTransitionTime"] == "2026-01-01T12:00:05Z"
    assert is_true(conditions, "Bound")


def test_long_messages_are_truncated():
    conditions: list[dict] = []
    set_condition(conditions, "Queued", True, "R", "x" * 5000, NOW)
    assert len(conditions[0]["message"]) == 1024


def test_removing_reports_whether_anything_was_there():
    conditions: list[dict] = []
    assert remove_condition(conditions, "Queued") is False
    set_condition(conditions, "Queued", True, "R", "", NOW)
    assert remove_condition(conditions, "Queued") is True and conditions == []
