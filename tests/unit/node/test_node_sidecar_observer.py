"""What the agent accepts from a pod sidecar's observer socket, where it looks for it, and replayed events."""

from __future__ import annotations

import base64
from datetime import UTC, datetime
from pathlib import Path

import pytest
from armnet_connector.cell import RolloutEvent
from armnet_connector.observer import frame_data, servos_data
from armnet_connector.telemetry import CameraFrame
from armnet_connector.telemetry_decode import ServoSample
from armnet_node import rollout_history as rh
from armnet_node.rollout_recorder import RolloutRecorder
from armnet_node.sidecar_observer import (
    observer_socket,
    parse_event,
    parse_frame,
    parse_monitor,
    parse_servos,
)

pytestmark = pytest.mark.unit

UID = "0f2b7c1e-8d4a-4f3e-9b6a-1c2d3e4f5a6b"


def test_the_socket_is_found_in_the_pods_observer_empty_dir_under_the_kubelet_root() -> None:
    assert observer_socket(Path("/srv/kubelet"), UID) == Path(
        f"/srv/kubelet/pods/{UID}/volumes/kubernetes.io~empty-dir/observer/observer.sock")


@pytest.mark.parametrize("uid", ["../../etc", "", f"{UID}/../x", "not-a-uid"])
def test_a_pod_uid_that_is_not_one_names_no_path(uid: str) -> None:
    assert observer_socket(Path("/var/lib/kubelet"), uid) is None


def test_servo_readings_cross_the_socket_unchanged() -> None:
    readings = {"arm": {"shoulder_pan": ServoSample(2048), "gripper": None}, "left": "the job has not read yet"}
    assert parse_servos(servos_data(readings)) == readings


@pytest.mark.parametrize("bad", [[], {"arm": 3}, {"arm": {"m": [1, 2]}}, {"arm": {"m": ["1", None, None]}},
                                 {"arm": {"m": [None, None, None]}}])
def test_servo_readings_of_another_shape_are_refused(bad: object) -> None:
    with pytest.raises(ValueError):
        parse_servos(bad)


def test_a_frame_crosses_the_socket_subsampled_to_at_most_640_wide() -> None:
    import numpy as np

    image = np.arange(960 * 1280 * 3, dtype=np.uint32).astype(np.uint8).reshape(960, 1280, 3)
    frame = parse_frame(frame_data(CameraFrame(image, bgr=True)))
    assert frame.image.shape == (480, 640, 3) and frame.bgr is True
    assert (frame.image == image[::2, ::2]).all()


@pytest.mark.parametrize("change", [
    {"shape": [2, 2, 4]}, {"shape": [2, 2]}, {"dtype": "float32"}, {"shape": [4000, 4000, 3]},
    {"data": base64.b64encode(b"short").decode()}, {"data": "not base64!"},
])
def test_a_frame_that_is_not_an_rgb_picture_of_its_stated_size_is_refused(change: dict[str, object]) -> None:
    import numpy as np

    good = frame_data(CameraFrame(np.zeros((2, 2, 3), np.uint8)))
    with pytest.raises(ValueError):
        parse_frame({**good, **change})


@pytest.mark.parametrize("bad", [{"kind": "begin", "at": True}, {"kind": "reset", "at": 1.0},
                                 {"kind": "begin", "at": 1.0, "index": "3"},
                                 {"kind": "begin", "at": 1.0, "outcome_controls": "yes"},
                                 {"kind": "verdict", "at": 1.0, "index": 1, "success": "yes"},
                                 {"kind": "verdict", "at": 1.0, "index": 1, "success": True, "score": float("inf")},
                                 {"kind": "verdict", "at": 1.0, "index": 1, "success": True, "frame_at": "now"}])
def test_a_rollout_event_of_another_shape_is_refused(bad: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        parse_event(bad)


def test_a_monitor_verdict_crosses_the_observer_socket_whole() -> None:
    event = parse_event({"kind": "verdict", "at": 5.0, "index": 2, "success": False, "score": 0.25, "frame_at": 4})
    assert (event.kind, event.index, event.success, event.score, event.frame_at) == ("verdict", 2, False, 0.25, 4.0)


def test_a_recorder_made_from_a_read_back_history_skips_the_events_it_already_holds() -> None:
    events = [RolloutEvent("begin", 100.0004, 0, 2, True), RolloutEvent("end", 101.5), RolloutEvent("begin", 102.0, 1, 2)]
    first = RolloutRecorder(lambda: events[:2])
    first.sync()
    read_back = rh.from_status(rh.as_status(first.history))  # what a restarted agent reads from the job
    again = RolloutRecorder(lambda: events, history=read_back)
    again.sync()
    assert [(e.index, e.started_at, e.open) for e in again.history] == [
        (0, datetime(1970, 1, 1, 0, 1, 40, tzinfo=UTC), False),
        (1, datetime(1970, 1, 1, 0, 1, 42, tzinfo=UTC), True)]


@pytest.mark.parametrize("bad", [[], {"complete": "yes", "score": 1.0}, {"complete": True},
                                 {"complete": True, "score": float("nan")}, {"complete": True, "score": True},
                                 {"complete": True, "score": 0.5, "frame_at": "now"}])
def test_a_monitor_verdict_of_another_shape_is_refused(bad: object) -> None:
    with pytest.raises(ValueError):
        parse_monitor(bad)


def test_no_monitor_is_no_verdict() -> None:
    assert parse_monitor(None) is None
