"""The ``region`` scorer on synthetic frames drawn with OpenCV, and the K-in-a-row streak.

Frames are BGR, as the monitor hands them to a scorer. The object is a red disc
(a colour range) or an ArUco marker; the target region is the right-hand middle
of a 320x240 picture.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from armnet_connector.scoring import (
    ArucoRegionScorer,
    ColourRegionScorer,
    FrameScore,
    HsvRange,
    Region,
    Streak,
)

pytestmark = pytest.mark.unit

W, H = 320, 240
REGION = Region(0.6, 0.3, 0.25, 0.4)  # pixels x 192..272, y 72..168
RED = HsvRange(hue_min=170, hue_max=8, saturation_min=120, value_min=60)  # wraps through red
RED_BGR = (30, 30, 230)
BACKGROUND_BGR = (40, 34, 32)
INSIDE = (230, 120)
JUST_OUTSIDE = (279, 120)  # 7 px right of the region's edge: most of the disc still overlaps it


def a_frame(*, disc_at: tuple[int, int] | None = None, radius: int = 10) -> np.ndarray:
    frame = np.empty((H, W, 3), np.uint8)
    frame[:] = BACKGROUND_BGR
    cv2.rectangle(frame, (20, 180), (300, 230), (110, 180, 60), -1)  # a green gauge, as the simulator draws
    cv2.line(frame, (40, 200), (150, 60), (40, 160, 230), 4)  # an orange link
    if disc_at is not None:
        cv2.circle(frame, disc_at, radius, RED_BGR, -1)
    return frame


def noisy(frame: np.ndarray, sigma: float, seed: int = 7) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(0, sigma, frame.shape)
    return np.clip(frame.astype(np.float64) + noise, 0, 255).astype(np.uint8)


def lit(frame: np.ndarray, gain: float) -> np.ndarray:
    return np.clip(frame.astype(np.float64) * gain, 0, 255).astype(np.uint8)


def with_marker(marker_id: int, at: tuple[int, int], side: int = 48) -> np.ndarray:
    frame = np.full((H, W, 3), 200, np.uint8)  # a light table: a marker needs its white border
    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), marker_id, side)
    x, y = at[0] - side // 2, at[1] - side // 2
    frame[y:y + side, x:x + side] = marker[:, :, None]
    return frame


COLOUR_CASES: list[tuple[str, Any, bool]] = [
    ("the disc in the region", a_frame(disc_at=INSIDE), True),
    ("a near miss just outside the region", a_frame(disc_at=JUST_OUTSIDE), False),
    ("the disc far away", a_frame(disc_at=(60, 40)), False),
    ("no disc", a_frame(), False),
    ("the disc in the region under sensor noise", noisy(a_frame(disc_at=INSIDE), 12), True),
    ("sensor noise and no disc", noisy(a_frame(), 25), False),
    ("the disc in the region, lights dimmed to 45 %", lit(a_frame(disc_at=INSIDE), 0.45), True),
    ("the disc in the region, lights up 30 %", lit(a_frame(disc_at=INSIDE), 1.3), True),
    ("the near miss, lights dimmed", lit(a_frame(disc_at=JUST_OUTSIDE), 0.45), False),
    ("a disc too small to be the object", a_frame(disc_at=INSIDE, radius=2), False),
    ("an empty (black) frame", np.zeros((H, W, 3), np.uint8), False),
]


@pytest.mark.parametrize(("case", "frame", "hit"), COLOUR_CASES, ids=[c[0] for c in COLOUR_CASES])
def test_the_colour_scorer_hits_only_when_the_object_is_in_the_region(case: str, frame: Any, hit: bool) -> None:
    score = ColourRegionScorer(REGION, RED, min_pixels=30).score(frame)
    assert score.hit is hit, score.detail
    assert score.score == 1.0 if hit else score.score < 1.0


def test_a_near_miss_scores_below_a_hit_but_above_nothing() -> None:
    scorer = ColourRegionScorer(REGION, RED)
    near = scorer.score(a_frame(disc_at=JUST_OUTSIDE))
    assert not near.hit and 0.0 < near.score < 1.0
    assert scorer.score(a_frame(disc_at=INSIDE)).score == 1.0


def test_stray_pixels_of_the_colour_in_the_region_do_not_count_beside_the_real_object() -> None:
    frame = a_frame(disc_at=(60, 40))
    frame[100:103, 200:203] = RED_BGR  # 9 stray red pixels inside the region
    assert not ColourRegionScorer(REGION, RED).score(frame).hit


WRONG_FRAMES: list[tuple[str, Any, str]] = [
    ("a grey 2-D frame", np.zeros((H, W), np.uint8), "height x width x 3 uint8"),
    ("a 4-channel frame", np.zeros((H, W, 4), np.uint8), "height x width x 3 uint8"),
    ("a float frame", np.zeros((H, W, 3), np.float32), "height x width x 3 uint8"),
    ("a zero-size frame", np.zeros((0, 0, 3), np.uint8), "smaller than"),
    ("a 4x4 frame", np.zeros((4, 4, 3), np.uint8), "smaller than"),
    ("no frame at all", None, "not an image"),
    ("a list of pixels", [[0, 0, 0]], "not an image"),
]


@pytest.mark.parametrize(("case", "frame", "says"), WRONG_FRAMES, ids=[c[0] for c in WRONG_FRAMES])
def test_a_frame_of_the_wrong_shape_is_a_miss_that_says_why(case: str, frame: Any, says: str) -> None:
    for scorer in (ColourRegionScorer(REGION, RED), ArucoRegionScorer(REGION, 7)):
        score = scorer.score(frame)
        assert not score.hit
        assert says in score.detail


ARUCO_CASES: list[tuple[str, Any, bool]] = [
    ("marker 7 in the region", with_marker(7, INSIDE), True),
    ("marker 7 outside the region", with_marker(7, (70, 70)), False),
    ("marker 7 centred just outside the region", with_marker(7, (280, 120)), False),
    ("another marker in the region", with_marker(3, INSIDE), False),
    ("marker 7 in the region under noise", noisy(with_marker(7, INSIDE), 10), True),
    ("marker 7 in the region, lights dimmed to 40 %", lit(with_marker(7, INSIDE), 0.4), True),
    ("no marker", np.full((H, W, 3), 200, np.uint8), False),
]


@pytest.mark.parametrize(("case", "frame", "hit"), ARUCO_CASES, ids=[c[0] for c in ARUCO_CASES])
def test_the_aruco_scorer_hits_only_when_its_marker_is_in_the_region(case: str, frame: Any, hit: bool) -> None:
    score = ArucoRegionScorer(REGION, 7).score(frame)
    assert score.hit is hit, score.detail


def test_the_region_scorer_works_at_any_picture_size() -> None:
    big = cv2.resize(a_frame(disc_at=INSIDE), (W * 2, H * 2), interpolation=cv2.INTER_NEAREST)
    assert ColourRegionScorer(REGION, RED).score(big).hit


HIT, MISS = FrameScore(True, 1.0, "in"), FrameScore(False, 0.4, "out")


def streak_of(scores: list[FrameScore], needed: int) -> Streak:
    streak = Streak(needed)
    for score in scores:
        streak = streak.advance(score)
    return streak


def test_k_consecutive_hits_make_the_verdict_complete() -> None:
    assert not streak_of([HIT, HIT], 3).verdict.complete
    assert streak_of([HIT, HIT, HIT], 3).verdict.complete
    assert streak_of([MISS, HIT, HIT, HIT], 3).verdict.complete


def test_a_miss_breaks_the_streak() -> None:
    verdict = streak_of([HIT, HIT, MISS, HIT, HIT], 3).verdict
    assert not verdict.complete and verdict.streak == 2


def test_a_frame_that_could_not_be_scored_breaks_the_streak() -> None:
    assert not streak_of([HIT, HIT], 2).miss("the scorer raised").verdict.complete


def test_the_verdict_scores_the_weakest_frame_of_its_streak() -> None:
    verdict = streak_of([HIT, FrameScore(True, 0.8, "edge"), HIT], 3).verdict
    assert verdict.complete and verdict.score == 0.8
    assert streak_of([], 3).verdict.score == 0.0
