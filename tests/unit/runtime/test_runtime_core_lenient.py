"""Reading an API object with the core models, leaving out only the parts that fail."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from armnet_core.lenient import read_leniently, read_parts
from armnet_core.resources import CellSpec, CellStatus, RobotJobStatus

pytestmark = pytest.mark.unit

STARTED = "2027-01-15T07:58:00.000Z"


def a_record(index: int, **extra: object) -> dict[str, object]:
    return {"index": index, "total": 3, "outcome": "unmarked", "startedAt": STARTED, **extra}


def test_a_well_formed_object_reads_whole_with_nothing_left_out() -> None:
    reading = read_parts(RobotJobStatus, {"phase": "running", "rollouts": [a_record(1), a_record(2)]})
    assert reading.dropped == ()
    assert reading.value is not None and [r.index for r in reading.value.rollouts] == [1, 2]


def test_a_field_of_the_wrong_type_is_left_out_and_its_default_applies() -> None:
    reading = read_parts(RobotJobStatus, {"phase": "running", "finishedAt": "yesterday", "queuePosition": "x"})
    assert reading.value is not None
    assert (reading.value.phase, reading.value.finished_at, reading.value.queue_position) == ("running", None, None)
    assert reading.dropped == ("finishedAt", "queuePosition")


def test_a_malformed_list_item_is_left_out_and_the_others_kept_in_order() -> None:
    rows = [a_record(1), None, "x", a_record(4), {"index": 5}, a_record(6, endedAt="never")]
    reading = read_parts(RobotJobStatus, {"phase": "running", "rollouts": rows})
    assert reading.value is not None and [r.index for r in reading.value.rollouts] == [1, 4, 6]
    assert reading.value.rollouts[2].ended_at is None  # an optional field that fails is read as absent
    assert reading.dropped == ("rollouts[1]", "rollouts[2]", "rollouts[4]", "rollouts[5].endedAt")


def test_an_item_whose_required_field_has_the_wrong_type_is_left_out_whole() -> None:
    status = read_leniently(RobotJobStatus, {"rollouts": [a_record(1), {**a_record(2), "index": "two"}]})
    assert status is not None and [r.index for r in status.rollouts] == [1]


def test_fifty_malformed_items_take_one_round() -> None:
    status = read_leniently(RobotJobStatus, {"rollouts": [None] * 50 + [a_record(7)]})
    assert status is not None and [r.index for r in status.rollouts] == [7]


def test_a_union_field_that_fails_is_left_out_by_its_own_name() -> None:
    spec = {"embodiment": "so101", "nodeName": "host-1",
            "cameras": {"front": {"indexOrPath": [1]}, "wrist": {"indexOrPath": "/dev/video2"}}}
    reading = read_parts(CellSpec, spec)
    assert reading.value is not None and list(reading.value.cameras) == ["wrist"]
    assert reading.dropped == ("cameras.front.indexOrPath", "cameras.front")


def test_an_object_missing_a_required_field_reads_as_none() -> None:
    assert read_leniently(CellSpec, {"nodeName": "host-1", "unschedulable": True}) is None
    assert read_leniently(CellStatus, "not an object") is None


def test_a_condition_with_an_unknown_status_goes_and_the_other_conditions_stay() -> None:
    status = read_leniently(CellStatus, {"lastHeartbeatTime": "2027-01-15T08:00:00Z", "conditions": [
        {"type": "InterlockClear", "status": "maybe"}, {"type": "AgentConnected", "status": "True"}]})
    assert status is not None and [c.type for c in status.conditions] == ["AgentConnected"]
    assert status.last_heartbeat_time == datetime(2027, 1, 15, 8, tzinfo=UTC)


def test_the_input_is_never_changed() -> None:
    data = {"rollouts": [None, a_record(1)]}
    read_leniently(RobotJobStatus, data)
    assert data == {"rollouts": [None, a_record(1)]}
