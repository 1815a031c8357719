"""The rollouts' pictures: written off the job's path, each rollout in its own folder, bounded."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from armnet_connector import rollout_frames
from armnet_connector.rollout_frames import QUEUE_SIZE, RolloutFrames

pytestmark = pytest.mark.unit

AT = 1_795_000_000.25  # 2026-11-18T11:06:40.250Z: a begin time with milliseconds


@dataclass
class Counters:
    rollout_frames_kept: int = 0
    rollout_frames_dropped: int = 0


def scene(value: int) -> np.ndarray:
    return np.full((48, 64, 3), value, dtype=np.uint8)


def test_a_rollout_keeps_its_first_verdict_and_last_picture_in_its_own_folder(tmp_path: Path) -> None:
    latest = [scene(10)]
    counters = Counters()
    frames = RolloutFrames(tmp_path, lambda: latest[0], counters).start()
    frames.begun(3, AT)
    latest[0] = scene(120)
    frames.judged()
    latest[0] = scene(250)
    frames.ended()
    frames.judged()  # after the end: no rollout, no picture
    frames.stop()

    [folder] = (tmp_path / "rollouts").iterdir()
    assert folder.name == "000003-20261118T110640.250Z"
    pictures = {p.name: cv2.imread(str(p)) for p in folder.iterdir()}
    assert sorted(pictures) == ["first.jpg", "last.jpg", "verdict.jpg"]
    assert [int(pictures[n].mean().round()) for n in ("first.jpg", "verdict.jpg", "last.jpg")] == [10, 120, 250]
    assert (counters.rollout_frames_kept, counters.rollout_frames_dropped) == (3, 0)


def test_a_rollout_begun_before_the_monitor_s_first_frame_takes_that_frame_as_its_first(tmp_path: Path) -> None:
    latest: list[np.ndarray | None] = [None]
    counters = Counters()
    frames = RolloutFrames(tmp_path, lambda: latest[0], counters).start()
    frames.judged()  # no rollout yet: nothing
    frames.scored(scene(5))  # no rollout waits for a first picture: nothing
    frames.begun(1, AT)  # the monitor's camera has given nothing yet
    latest[0] = scene(60)
    frames.scored(scene(60))
    frames.scored(scene(70))  # only the first frame scored after the begin
    frames.ended()
    frames.stop()
    [folder] = (tmp_path / "rollouts").iterdir()
    assert {p.name: int(cv2.imread(str(p)).mean().round()) for p in folder.iterdir()} == {
        "first.jpg": 60, "last.jpg": 60}
    assert counters.rollout_frames_kept == 2


def test_a_writer_that_is_behind_drops_pictures_and_never_makes_the_job_wait(tmp_path: Path) -> None:
    counters = Counters()
    frames = RolloutFrames(tmp_path, lambda: scene(1), counters)  # the writer not started: nothing leaves the queue
    frames.begun(1, AT)
    for _ in range(QUEUE_SIZE + 4):
        frames.judged()
    assert counters.rollout_frames_dropped == 5  # the queue holds QUEUE_SIZE: the first plus 31 verdicts


def test_past_the_cap_of_rollouts_pictures_are_counted_not_kept(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rollout_frames, "MAX_ROLLOUTS", 2)
    counters = Counters()
    frames = RolloutFrames(tmp_path, lambda: scene(1), counters).start()
    for index in range(4):
        frames.begun(index, AT + index)
        frames.ended()
    frames.stop()
    assert len(list((tmp_path / "rollouts").iterdir())) == 2
    assert (counters.rollout_frames_kept, counters.rollout_frames_dropped) == (4, 2)
