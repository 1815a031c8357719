"""The completion monitor's thread: K frames in a row, failing scorers, ``block=True``, its camera.

Frames are the simulator's own pictures (``render_arms``), scored by the real
region scorer against the simulator's target pad. ``ShownFrames`` is a frame
source whose frames and clock the test sets (the monitor's ``FrameSource``
interface); the last tests use the simulator's real camera through the
connector's camera factory.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from armnet_connector.cell import Counters
from armnet_connector.completion import CameraCompletionMonitor, CameraFrames, Frame
from armnet_connector.config import CameraConfig
from armnet_connector.hardware import simulated_camera_factory
from armnet_connector.scoring import FrameScore
from armnet_core.cell_completion import CompletionConfig
from armnet_sim.render import TARGET_POSE, render_arms, target_region

pytestmark = pytest.mark.unit

W, H = 640, 480
REST = {"shoulder_lift": 0.0, "elbow_flex": 0.0, "wrist_flex": 0.0}


def bgr_picture(joints: dict[str, float]) -> np.ndarray:
    return np.ascontiguousarray(render_arms({"arm": joints}, W, H)[:, :, ::-1])


ON_TARGET, AT_REST = bgr_picture(dict(TARGET_POSE)), bgr_picture(REST)


def a_config(**overrides: Any) -> CompletionConfig:
    x, y, w, h = target_region(W, H)
    data: dict[str, Any] = {
        "camera": "front",
        "region": {"left": x, "top": y, "width": w, "height": h},
        "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80},
        "consecutiveFrames": 3,
        "rateHz": 30,
    }
    data.update(overrides)
    return CompletionConfig.model_validate(data)


class ShownFrames:
    """Frames the test shows, one at a time, on a clock the test sets."""

    def __init__(self) -> None:
        self.frame: Frame | None = None
        self.now = 0.0
        self.closed = 0
        self.looks = 0

    def show(self, image: np.ndarray, stamp: float) -> None:
        self.frame = Frame(image, stamp)

    def open(self) -> None:
        pass

    def latest(self) -> Frame | None:
        self.looks += 1
        return self.frame

    def clock(self) -> float:
        return self.now

    def close(self) -> None:
        self.closed += 1


def wait_until(check: Callable[[], bool], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if check():
            return True
        time.sleep(0.01)
    return check()


@pytest.fixture
def run_monitor() -> Iterator[Callable[..., CameraCompletionMonitor]]:
    started: list[CameraCompletionMonitor] = []

    def start(config: CompletionConfig, source: Any, counters: Counters, **kwargs: Any) -> CameraCompletionMonitor:
        monitor = CameraCompletionMonitor(config, source, counters, **kwargs).start()
        started.append(monitor)
        return monitor

    yield start
    for monitor in started:
        monitor.stop()


def show_frames(source: ShownFrames, counters: Counters, image: np.ndarray, count: int, start: float) -> float:
    """Show ``count`` new frames one after another, each once scored; the last stamp."""
    stamp = start
    for _ in range(count):
        stamp += 1.0
        scored = counters.completion_frames_scored
        source.show(image, stamp)
        assert wait_until(lambda scored=scored: counters.completion_frames_scored > scored)
    return stamp


def test_the_episode_is_complete_once_k_frames_in_a_row_show_the_arm_on_the_target(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    source, counters = ShownFrames(), Counters()
    monitor = run_monitor(a_config(), source, counters)
    stamp = show_frames(source, counters, ON_TARGET, 2, 0.0)
    assert monitor.is_complete(block=False) == (False, False)
    show_frames(source, counters, ON_TARGET, 1, stamp)
    assert monitor.is_complete(block=False) == (True, True)
    assert monitor.verdict().score == 1.0


def test_the_arm_leaving_the_target_makes_the_episode_not_complete_again(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    source, counters = ShownFrames(), Counters()
    monitor = run_monitor(a_config(consecutiveFrames=1), source, counters)
    stamp = show_frames(source, counters, ON_TARGET, 1, 0.0)
    assert monitor.is_complete(block=False)[0]
    show_frames(source, counters, AT_REST, 1, stamp)
    assert monitor.is_complete(block=False) == (False, False)


def test_a_frame_already_scored_is_not_scored_again(run_monitor: Callable[..., CameraCompletionMonitor]) -> None:
    source, counters = ShownFrames(), Counters()
    monitor = run_monitor(a_config(consecutiveFrames=2), source, counters)
    show_frames(source, counters, ON_TARGET, 1, 0.0)
    looks = source.looks
    assert wait_until(lambda: source.looks >= looks + 3)  # it looked at the same frame again and again
    assert counters.completion_frames_scored == 1
    assert not monitor.is_complete(block=False)[0]
    assert monitor.verdict().streak == 1


class Raising:
    def score(self, frame: Any) -> FrameScore:
        raise ZeroDivisionError("a bug in the scorer")


def test_a_scorer_that_raises_is_counted_and_answers_not_complete(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    source, counters = ShownFrames(), Counters()
    monitor = run_monitor(a_config(consecutiveFrames=1), source, counters, scorer=Raising())
    show_frames(source, counters, ON_TARGET, 2, 0.0)
    assert counters.completion_scorer_errors == 2
    assert monitor.is_complete(block=False) == (False, False)
    assert "ZeroDivisionError: a bug in the scorer" in monitor.verdict().detail


def test_a_classifier_whose_model_is_not_a_model_counts_each_failed_score_and_answers_not_complete(
    run_monitor: Callable[..., CameraCompletionMonitor], tmp_path: Path,
) -> None:
    model = tmp_path / "reach.onnx"
    model.write_text("not a model")
    config = CompletionConfig.model_validate({"camera": "front", "scorer": "classifier", "rateHz": 30,
                                              "consecutiveFrames": 1, "classifier": {"model": str(model)}})
    source, counters = ShownFrames(), Counters()
    monitor = run_monitor(config, source, counters)  # the connector's start does not load the model
    show_frames(source, counters, ON_TARGET, 3, 0.0)
    assert counters.completion_scorer_errors == 3
    assert monitor.is_complete(block=False) == (False, False)
    assert "is not an ONNX model OpenCV can run" in monitor.verdict().detail


class Hanging:
    """A scorer that does not return until released, then reports a hit."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.entered = threading.Event()
        self.calls = 0

    def score(self, frame: Any) -> FrameScore:
        self.calls += 1
        if self.calls > 1:
            self.entered.set()
            self.release.wait(60)
        return FrameScore(True, 1.0, "hit")


def test_a_hung_scorer_answers_not_complete_at_once_and_its_late_hit_does_not_count(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    source, counters, scorer = ShownFrames(), Counters(), Hanging()
    monitor = run_monitor(a_config(consecutiveFrames=1), source, counters, scorer=scorer)
    stamp = show_frames(source, counters, ON_TARGET, 1, 0.0)
    assert monitor.is_complete(block=False)[0]  # the first score returned at once
    source.show(ON_TARGET, stamp + 1)
    assert scorer.entered.wait(20)
    assert wait_until(lambda: "running for over" in monitor.verdict().detail)
    assert monitor.is_complete(block=False) == (False, False)
    scorer.release.set()
    assert wait_until(lambda: counters.completion_scorer_slow == 1)
    assert monitor.is_complete(block=False) == (False, False)
    assert "over 1 s" in monitor.verdict().detail


def test_block_waits_until_a_frame_newer_than_the_call_is_scored(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    source, counters = ShownFrames(), Counters()
    monitor = run_monitor(a_config(consecutiveFrames=1), source, counters)
    show_frames(source, counters, AT_REST, 1, 0.0)
    source.now = 10.0  # the call comes after the frame shown at 1.0
    answers: list[tuple[bool, bool]] = []
    asking = threading.Thread(target=lambda: answers.append(monitor.is_complete(block=True)))
    asking.start()
    source.show(ON_TARGET, 11.0)
    asking.join(30)
    assert answers == [(True, True)]
    assert counters.completion_block_timeouts == 0


def test_block_answers_not_complete_when_no_frame_newer_than_the_call_comes(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    source, counters = ShownFrames(), Counters()
    monitor = run_monitor(a_config(consecutiveFrames=1), source, counters)
    show_frames(source, counters, ON_TARGET, 1, 0.0)
    assert monitor.is_complete(block=False)[0]
    source.now = 10.0  # the camera froze: its newest frame is older than the call
    assert monitor.is_complete(block=True) == (False, False)
    assert counters.completion_block_timeouts == 1


def sim_camera_frames(joints: dict[str, float]) -> CameraFrames:
    camera = CameraConfig(index_or_path="front", fps=30, width=W, height=H)
    return CameraFrames(simulated_camera_factory(source=lambda: joints), "front", camera)


def test_the_simulated_camera_showing_the_arm_on_the_target_is_scored_complete(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    counters = Counters()
    monitor = run_monitor(a_config(), sim_camera_frames(dict(TARGET_POSE)), counters)
    assert wait_until(lambda: monitor.is_complete(block=False) == (True, True))
    assert counters.completion_camera_errors == 0


def test_the_simulated_camera_showing_the_arm_at_rest_is_not_complete(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    counters = Counters()
    monitor = run_monitor(a_config(), sim_camera_frames(REST), counters)
    assert monitor.is_complete(block=True) == (False, False)
    assert counters.completion_frames_scored >= 1
    assert monitor.verdict().streak == 0


def test_a_camera_that_cannot_open_is_counted_and_answers_not_complete(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    def broken(name: str, camera: CameraConfig, requested: Any) -> Any:
        raise ConnectionError("no /dev/video0")

    counters = Counters()
    source = CameraFrames(broken, "front", CameraConfig(index_or_path=0))
    monitor = run_monitor(a_config(), source, counters)
    assert wait_until(lambda: counters.completion_camera_errors >= 1)
    assert monitor.is_complete(block=False) == (False, False)


def test_the_monitor_skips_a_frame_whose_lock_a_reader_holds_instead_of_waiting(
    run_monitor: Callable[..., CameraCompletionMonitor],
) -> None:
    frames = sim_camera_frames(dict(TARGET_POSE))
    frames.open()
    try:
        assert wait_until(lambda: frames.latest() is not None)
        camera = frames._camera
        with camera.frame_lock:
            assert frames.latest() is None  # bounded: it gave up on the lock, never blocked on it
        latest = frames.latest()
        assert latest is not None
        assert np.array_equal(latest.image, cv2.cvtColor(camera.latest_frame, cv2.COLOR_RGB2BGR))
    finally:
        frames.close()
