"""The FMS keeps each cell's latest frames and last seconds of servo readings, bounded, from hostile messages."""

from __future__ import annotations

import json
from typing import Any

import pytest
from armnet_fms.telemetry import (
    MAX_ARMS,
    MAX_CAMERAS,
    MAX_FRAME_BYTES,
    MAX_MOTORS,
    TelemetryStore,
    parse_servos,
    parse_subject,
)

pytestmark = pytest.mark.unit

JPEG = b"\xff\xd8\xff\xe0" + b"\x00" * 64


def reading(position: int = 2048, load: int = 5, temperature: int = 30, source: str = "idle") -> bytes:
    return json.dumps({"t": 0, "source": source, "arms": {"arm": {"motors": {
        "gripper": {"position": position, "load": load, "temperature": temperature}}}}}).encode()


def test_subjects_name_a_cells_servos_or_one_of_its_cameras() -> None:
    assert parse_subject("telemetry.cell-1.servos") == ("cell-1", None)
    assert parse_subject("telemetry.cell-1.camera.front") == ("cell-1", "front")


@pytest.mark.parametrize("subject", ["telemetry.cell-1", "telemetry.cell-1.camera", "logs.a.b.stdout",
                                     "telemetry.cell-1.camera.front.extra", "telemetry.cell 1.servos"])
def test_other_subjects_are_not_telemetry(subject: str) -> None:
    assert parse_subject(subject) is None


def test_only_the_latest_frame_of_a_camera_is_kept() -> None:
    store = TelemetryStore()
    store.accept("telemetry.c.camera.front", JPEG + b"old", 1.0)
    store.accept("telemetry.c.camera.front", JPEG + b"new", 2.0)
    frame = store.frame("c", "front")
    assert frame is not None and frame.jpeg.endswith(b"new") and frame.at == 2.0
    assert store.frames_held == 1


def test_a_frame_that_is_not_jpeg_or_too_large_is_refused() -> None:
    store = TelemetryStore()
    assert not store.accept("telemetry.c.camera.front", b"<svg onload=alert(1)>", 1.0)
    assert not store.accept("telemetry.c.camera.front", JPEG + b"\x00" * MAX_FRAME_BYTES, 1.0)
    assert store.frame("c", "front") is None
    assert store.refused == 2


def test_a_cell_holds_at_most_a_few_cameras() -> None:
    store = TelemetryStore()
    results = [store.accept(f"telemetry.c.camera.cam{i}", JPEG, 1.0) for i in range(MAX_CAMERAS + 3)]
    assert results.count(True) == MAX_CAMERAS
    assert store.frames_held == MAX_CAMERAS


def test_the_least_recently_heard_cell_is_forgotten_beyond_the_cap() -> None:
    store = TelemetryStore(max_cells=2)
    store.accept("telemetry.a.camera.front", JPEG, 1.0)
    store.accept("telemetry.b.camera.front", JPEG, 2.0)
    store.accept("telemetry.a.servos", reading(), 3.0)  # a is heard again: b is now the oldest
    store.accept("telemetry.c.camera.front", JPEG, 4.0)
    assert store.frame("b", "front") is None
    assert store.frame("a", "front") is not None and store.frame("c", "front") is not None


def test_servo_series_cover_the_last_seconds_oldest_first_with_ages() -> None:
    store = TelemetryStore(history_s=30)
    for t, position in ((0.0, 100), (10.0, 200), (35.0, 300)):
        store.accept("telemetry.c.servos", reading(position=position), t)
    view = store.view("c", 36.0)
    assert view["series"] == [{"arm": "arm", "motor": "gripper", "points": [[26.0, 200, 5, 30], [1.0, 300, 5, 30]]}]
    assert view["ageS"] == 1.0 and view["source"] == "idle"


def test_the_cameras_are_listed_with_their_frame_age() -> None:
    store = TelemetryStore()
    store.accept("telemetry.c.camera.wrist", JPEG, 9.5)
    assert store.view("c", 10.0)["cameras"] == [{"name": "wrist", "ageS": 0.5}]


def test_a_cell_never_heard_has_an_empty_view() -> None:
    assert TelemetryStore().view("nobody", 1.0) == {
        "cell": "nobody", "cameras": [], "series": [], "source": None, "ageS": None, "unread": [], "errors": [],
        "monitor": None}


def test_a_silent_motor_has_no_point_at_that_read() -> None:
    data = json.dumps({"source": "job", "arms": {"arm": {"motors": {"gripper": None}}}}).encode()
    store = TelemetryStore()
    store.accept("telemetry.c.servos", data, 1.0)
    assert store.view("c", 1.0)["series"] == [{"arm": "arm", "motor": "gripper", "points": []}]


def test_an_arm_that_was_not_read_shows_its_reason() -> None:
    data = json.dumps({"source": "job", "arms": {"arm": {"error": "busy"}}}).encode()
    store = TelemetryStore()
    store.accept("telemetry.c.servos", data, 1.0)
    assert store.view("c", 1.0)["errors"] == [{"arm": "arm", "error": "busy"}]


def test_an_arm_the_latest_reading_could_not_read_has_no_line_from_older_reads() -> None:
    store = TelemetryStore()
    two_arms = {"left": {"motors": {"gripper": {"position": 1, "load": 2, "temperature": 30}}},
                "right": {"motors": {"gripper": {"position": 5, "load": 6, "temperature": 31}}}}
    store.accept("telemetry.c.servos", json.dumps({"source": "idle", "arms": two_arms}).encode(), 1.0)
    later = {"left": {"error": "the job has not connected this arm's bus"},
             "right": {"motors": {"gripper": {"position": 7}}}}
    store.accept("telemetry.c.servos", json.dumps({"source": "job", "arms": later}).encode(), 2.0)
    view = store.view("c", 2.0)
    assert [(s["arm"], s["motor"]) for s in view["series"]] == [("right", "gripper")]
    assert view["errors"] == [{"arm": "left", "error": "the job has not connected this arm's bus"}]


def test_while_a_job_runs_no_load_or_temperature_is_served_even_from_reads_before_it() -> None:
    store = TelemetryStore()
    store.accept("telemetry.c.servos", reading(position=100, load=5, temperature=30), 1.0)
    store.accept("telemetry.c.servos", reading(position=110, source="job"), 2.0)
    view = store.view("c", 2.0)
    assert view["unread"] == ["load", "temperature"]
    assert view["series"][0]["points"] == [[1.0, 100, None, None], [0.0, 110, None, None]]
    # The job over, the idle agent reads everything again: the whole window is served as read.
    store.accept("telemetry.c.servos", reading(position=120, load=7, temperature=31), 3.0)
    view = store.view("c", 3.0)
    assert view["unread"] == []
    assert view["series"][0]["points"][0] == [2.0, 100, 5, 30]


@pytest.mark.parametrize("body", [
    b"not json", b"[1, 2]", b'{"arms": []}', json.dumps({"arms": {"x": "y"}}).encode() + b" " * 70_000,
])
def test_a_message_that_is_not_a_reading_is_refused(body: bytes) -> None:
    store = TelemetryStore()
    assert not store.accept("telemetry.c.servos", body, 1.0)
    assert store.view("c", 1.0)["series"] == []


@pytest.mark.parametrize("bad", ["2048", True, float("nan"), 1e30, None, [1]])
def test_a_value_that_is_not_a_plausible_number_makes_the_motor_silent(bad: Any) -> None:
    data = json.dumps({"arms": {"arm": {"motors": {"gripper": {"position": bad, "load": 0, "temperature": 30}}}}})
    parsed = parse_servos(data.encode(), 1.0)
    assert parsed is not None and parsed.motors == (("arm", "gripper", None),)


def test_an_unknown_source_is_not_echoed() -> None:
    parsed = parse_servos(reading(source="<script>"), 1.0)
    assert parsed is not None and parsed.source == "unknown"


def test_telemetry_of_a_cell_the_fleet_does_not_know_is_refused() -> None:
    store = TelemetryStore(known_cells=lambda: {"cell-1"})
    assert store.accept("telemetry.cell-1.servos", reading(), 1.0)
    assert not store.accept("telemetry.forged-1.servos", reading(), 1.0)
    assert not store.accept("telemetry.forged-1.camera.front", JPEG, 1.0)
    assert store.view("forged-1", 1.0)["series"] == [] and store.frames_held == 0
    assert store.refused == 2


def test_frames_stay_within_the_byte_budget_dropping_the_oldest_anywhere() -> None:
    store = TelemetryStore(frame_budget_bytes=3 * 1000)
    for i, cell in enumerate(("a", "b", "c", "d")):
        store.accept(f"telemetry.{cell}.camera.front", JPEG + b"\x00" * (1000 - len(JPEG)), float(i))
    assert store.frame_bytes == 3000 and store.frames_held == 3
    assert store.frame("a", "front") is None and store.frame("d", "front") is not None


def test_a_newer_frame_of_a_camera_replaces_its_bytes_in_the_budget() -> None:
    store = TelemetryStore()
    store.accept("telemetry.c.camera.front", JPEG + b"\x00" * 100, 1.0)
    store.accept("telemetry.c.camera.front", JPEG, 2.0)
    assert store.frame_bytes == len(JPEG)


def test_a_reading_keeps_at_most_a_few_arms_of_a_few_motors() -> None:
    arms = {f"arm{a}": {"motors": {f"m{m}": {"position": 1} for m in range(30)}} for a in range(10)}
    parsed = parse_servos(json.dumps({"source": "idle", "arms": arms}).encode(), 1.0)
    assert parsed is not None
    assert len({arm for arm, _, _ in parsed.motors}) == MAX_ARMS
    assert len(parsed.motors) == MAX_ARMS * MAX_MOTORS


def test_a_jobs_position_only_reading_keeps_the_position_with_no_load_or_temperature() -> None:
    store = TelemetryStore()
    body = json.dumps({"source": "job", "arms": {"arm": {"motors": {"gripper": {"position": 2100}}}}}).encode()
    assert store.accept("telemetry.c.servos", body, 1.0)
    assert store.view("c", 1.0)["series"] == [{"arm": "arm", "motor": "gripper", "points": [[0.0, 2100, None, None]]}]


def monitor(complete: Any = True, score: Any = 0.93) -> bytes:
    return json.dumps({"t": 0, "complete": complete, "score": score, "frameAt": 1.0}).encode()


def test_the_monitors_verdict_now_is_shown_until_it_is_stale() -> None:
    store = TelemetryStore(known_cells=lambda: {"c"})
    assert store.view("c", 0.0)["monitor"] is None
    assert store.accept("telemetry.c.monitor", monitor(False, 0.2), 1.0)
    assert store.accept("telemetry.c.monitor", monitor(True, 0.93), 2.0)

    assert store.view("c", 2.5)["monitor"] == {"complete": True, "score": 0.93, "ageS": 0.5}
    assert store.view("c", 8.0)["monitor"] is None  # no word for 5 s: the job ended


@pytest.mark.parametrize("subject, data", [
    ("telemetry.other.monitor", monitor()),  # a cell the fleet does not know
    ("telemetry.c.monitor", monitor(complete="yes")),
    ("telemetry.c.monitor", monitor(score=1.5)),
    ("telemetry.c.monitor", monitor(score=float("nan"))),
    ("telemetry.c.monitor", monitor(score=True)),
    ("telemetry.c.monitor", b"[1, 2]"),
    ("telemetry.c.monitor", b"{" + b" " * 2000 + b"}"),
    ("telemetry.c.monitor.extra", monitor()),
])
def test_a_monitor_message_that_is_not_a_verdict_of_a_known_cell_is_refused(subject: str, data: bytes) -> None:
    store = TelemetryStore(known_cells=lambda: {"c"})
    assert not store.accept(subject, data, 1.0)
    assert store.view("c", 1.0)["monitor"] is None and store.refused == 1
