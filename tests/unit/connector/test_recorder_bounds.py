"""The flight recorder's writers on their own: bounded when behind, whole files only, and what
a connector that dies leaves (servo_trace, camera_video)."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
import pytest
from armnet_connector import camera_video, servo_trace
from armnet_connector.camera_video import CameraVideo
from armnet_connector.cell import Counters
from armnet_connector.servo_trace import GOAL, PRESENT, ServoTrace, trace_call


@pytest.fixture
def quick_parts(monkeypatch: pytest.MonkeyPatch) -> None:
    """A part every 50 ms, gathered every 20 ms (the connector's: every 2 s, every 1 s)."""
    monkeypatch.setattr(servo_trace, "PART_S", 0.05)
    monkeypatch.setattr(servo_trace, "GATHER_S", 0.02)


def wait_for(condition, timeout_s: float = 60.0) -> None:  # type: ignore[no-untyped-def]
    """Until ``condition()``; the first writer of a test process imports pyarrow and pandas, seconds under load."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_parts_are_written_as_the_job_runs_so_a_connector_that_dies_keeps_them(
    tmp_path: Path, quick_parts: None,
) -> None:
    counters = Counters()
    trace = ServoTrace(tmp_path, counters).start()
    trace.positions(PRESENT, "left", {"elbow_flex": 1.5, "gripper": 40}, True)
    wait_for(lambda: counters.trace_rows_written == 2)
    trace.positions(GOAL, "left", {"elbow_flex": 2.0}, False)
    wait_for(lambda: counters.trace_rows_written == 3)
    # Not stopped (a connector killed now): every part on disk is whole and reads as one table.
    parts = sorted(p.name for p in (tmp_path / "servo-trace").iterdir())
    assert parts == ["part-000001.parquet", "part-000002.parquet"]
    rows = pq.read_table(tmp_path / "servo-trace").to_pylist()
    assert [(r["kind"], r["motor"], r["value"], r["units"]) for r in rows] == [
        (PRESENT, "elbow_flex", 1.5, "normalized"), (PRESENT, "gripper", 40.0, "normalized"),
        (GOAL, "elbow_flex", 2.0, "raw"),
    ]
    trace.stop(60)


def test_rows_past_the_pending_cap_are_dropped_and_counted_never_waited_for(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(servo_trace, "MAX_PENDING", 3)
    monkeypatch.setattr(servo_trace, "EVENT_ROOM", 2)
    counters = Counters()
    trace = ServoTrace(tmp_path, counters)  # not started: nothing drains
    for index in range(4):
        trace.positions(PRESENT, "arm", {"elbow_flex": float(index), "gripper": 1.0}, True)  # the 4th: 2 rows dropped
    trace.event("clamp", motor="elbow_flex")  # events have room past the positions' cap
    trace.event("interlock_trip", detail="tripped")
    trace.event("rollout_end")  # past that room too: dropped
    trace.start().stop(60)  # the first writer of a test process imports pyarrow: give it the time
    assert (counters.trace_rows_written, counters.trace_rows_dropped) == (8, 3)
    kept = pq.read_table(tmp_path / "servo-trace").to_pylist()
    assert [r["kind"] for r in kept][-2:] == ["clamp", "interlock_trip"]


def test_a_part_that_cannot_be_written_is_counted_and_the_trace_goes_on(tmp_path: Path) -> None:
    counters = Counters()
    (tmp_path / "servo-trace").write_text("a file where the folder should be")
    trace = ServoTrace(tmp_path, counters).start()
    trace.event("reset_begin")
    trace.stop(60)
    assert (counters.trace_rows_written, counters.trace_rows_dropped) == (0, 1)


def test_a_long_detail_is_cut_and_a_value_that_is_no_number_is_kept_empty(tmp_path: Path) -> None:
    counters = Counters()
    trace = ServoTrace(tmp_path, counters).start()
    trace.event("refusal", detail="why " * 1000)
    trace_call(trace, "arm", "sync_write", ["Goal_Position", {"elbow_flex": "not a number"}], {}, None)
    trace_call(trace, "arm", "write", ["Goal_Position", "gripper", 12.5], {"normalize": False}, None)
    trace_call(trace, "arm", "sync_read", ["Torque_Enable"], {}, {"gripper": 1})  # not a position: not traced
    trace.stop(60)
    rows = pq.read_table(tmp_path / "servo-trace").to_pylist()
    assert len(rows[0]["detail"]) == servo_trace.MAX_DETAIL_CHARS
    assert [(r["motor"], r["value"], r["units"]) for r in rows[1:]] == [
        ("elbow_flex", None, "normalized"), ("gripper", 12.5, "raw"),
    ]


def picture(seed: int, shape: tuple[int, ...] = (120, 160, 3)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def decoded_frames(path: Path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(container.streams.video[0])]


@pytest.fixture
def roomy_queue(monkeypatch: pytest.MonkeyPatch) -> None:
    """A queue that holds every frame a test feeds: what is kept does not hang on the machine's load."""
    monkeypatch.setattr(camera_video, "QUEUE_SIZE", 1000)


def test_a_camera_faster_than_the_video_s_rate_is_kept_at_that_rate(tmp_path: Path, roomy_queue: None) -> None:
    counters = Counters()
    video = CameraVideo(tmp_path, counters, max_fps=15).start()
    tap = video.tap("front")
    start = time.monotonic()
    for index in range(90):  # 3 s of a 30 fps camera, its clock a little uneven (fed 3x as fast)
        tap(picture(index), start + index / 30 + (0.002 if index % 2 else 0.0))
    wait_for(lambda: counters.video_frames_written + counters.video_frames_dropped >= 45)
    video.stop(60)
    frames = decoded_frames(tmp_path / "videos" / "front.mp4")
    assert counters.video_frames_dropped == 0 and len(frames) == counters.video_frames_written == 45


def test_a_new_frame_size_starts_a_new_file_and_what_is_no_picture_is_dropped(
    tmp_path: Path, roomy_queue: None, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(camera_video, "MAX_FILES_PER_CAMERA", 3)
    counters = Counters()
    video = CameraVideo(tmp_path, counters, max_fps=0).start()  # 0: every frame
    tap = video.tap("wrist/cam 1")  # a name that is no file name is made one
    start = time.monotonic()
    tap(picture(1), start)
    tap(picture(2, (121, 163, 3)), start + 0.1)  # odd sizes: cut to even (H.264's 4:2:0)
    tap(picture(3, (64, 64)), start + 0.2)  # grey
    tap(np.zeros((10, 10, 4), np.uint8), start + 0.3)  # four channels: not kept
    tap(np.zeros((10, 10, 3), np.float32), start + 0.4)  # not 8-bit: not kept
    tap(picture(5, (40, 40, 3)), start + 0.5)  # a fourth size: past the camera's files, not kept
    wait_for(lambda: counters.video_frames_written + counters.video_frames_dropped == 6)
    video.stop(60)
    names = sorted(p.name for p in (tmp_path / "videos").glob("*.mp4"))
    assert names == ["wrist_cam_1-2.mp4", "wrist_cam_1-3.mp4", "wrist_cam_1.mp4"]
    assert decoded_frames(tmp_path / "videos" / "wrist_cam_1-2.mp4")[0].shape == (120, 162, 3)
    assert (counters.video_frames_written, counters.video_frames_dropped) == (3, 3)


def test_a_full_queue_drops_the_frame_and_never_blocks_the_camera(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(camera_video, "QUEUE_SIZE", 2)
    counters = Counters()
    video = CameraVideo(tmp_path, counters, max_fps=0)  # not started: nothing encodes
    tap = video.tap("front")
    began = time.monotonic()
    for index in range(10):
        tap(picture(index), 1000.0 + index)
    assert time.monotonic() - began < 1.0
    assert counters.video_frames_dropped == 8


def test_a_video_cut_short_by_a_crash_plays_up_to_its_last_fragment(tmp_path: Path, roomy_queue: None) -> None:
    counters = Counters()
    video = CameraVideo(tmp_path, counters, max_fps=0).start()
    tap = video.tap("front")
    start = time.monotonic()
    total = 2 * camera_video.KEYFRAME_INTERVAL + 5
    for index in range(total):  # a slowly changing scene: keyframes only where the encoder is told
        tap(np.full((120, 160, 3), 60 + index, np.uint8), start + index / 30)
    wait_for(lambda: counters.video_frames_written + counters.video_frames_dropped == total)
    assert counters.video_frames_dropped == 0
    cut = tmp_path / "cut.mp4"
    shutil.copyfile(tmp_path / "videos" / "front.mp4", cut)  # the file as a killed connector leaves it
    played = 0
    with av.open(str(cut)) as container:  # as a player does: up to the first packet cut short
        try:
            for _frame in container.decode(container.streams.video[0]):
                played += 1
        except av.error.InvalidDataError:
            pass
    # The fragments closed by a keyframe are there; the frames after the last keyframe are not yet.
    assert 2 * camera_video.KEYFRAME_INTERVAL - 1 <= played < total, played
    video.stop(60)


def test_a_long_job_s_trace_has_fewer_parts_each_hour_so_a_day_stays_within_the_upload_cap() -> None:
    from armnet_node.artifacts.model import DEFAULT_MAX_FILES

    assert servo_trace.part_period_s(0) == servo_trace.PART_S
    assert servo_trace.part_period_s(3600 * 1.5) == 2 * servo_trace.PART_S
    parts_in_a_day = sum(3600 / servo_trace.part_period_s(hour * 3600) for hour in range(24))
    assert parts_in_a_day < DEFAULT_MAX_FILES / 2, parts_in_a_day


def test_rows_past_the_job_s_bytes_are_counted_not_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, quick_parts: None,
) -> None:
    monkeypatch.setattr(servo_trace, "MAX_BYTES", 1)
    counters = Counters()
    trace = ServoTrace(tmp_path, counters).start()
    trace.event("reset_begin")
    wait_for(lambda: counters.trace_rows_written == 1)
    trace.event("reset_end")
    trace.stop(60)
    assert (counters.trace_rows_written, counters.trace_rows_dropped) == (1, 1)


def test_frames_past_the_job_s_video_bytes_are_counted_not_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, roomy_queue: None,
) -> None:
    monkeypatch.setattr(camera_video, "MAX_BYTES", 1)
    monkeypatch.setattr(camera_video, "SIZE_CHECK_FRAMES", 2)
    counters = Counters()
    video = CameraVideo(tmp_path, counters, max_fps=0).start()
    tap = video.tap("front")
    for index in range(6):
        tap(picture(index), 1000.0 + index)
    wait_for(lambda: counters.video_frames_written + counters.video_frames_dropped == 6)
    video.stop(60)
    assert (counters.video_frames_written, counters.video_frames_dropped) == (1, 5)
    assert len(decoded_frames(tmp_path / "videos" / "front.mp4")) == 1  # closed whole
