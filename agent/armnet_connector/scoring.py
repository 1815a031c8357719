"""Scoring camera frames for the completion monitor (pure: frames in, verdicts out).

This module owns the scorer interface and the classical ``region`` scorer: is an
object (of a colour range, or an ArUco marker of one id) inside a target region
of the picture? A per-frame :class:`FrameScore` says so for one frame; the
:class:`Streak` turns scores into a :class:`Verdict` (complete once K
consecutive frames hit). It never opens a camera, starts a thread or keeps a
clock: the monitor (``completion``) feeds it frames and decides when.

Frames are OpenCV's ``height x width x 3`` uint8 in BGR order; a frame of any
other shape is a miss that says why, never an exception, so a camera that
changes its format cannot crash the monitor.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

Image = npt.NDArray[np.uint8]

#: Below this many pixels a side, a picture holds nothing the scorer can find.
MIN_FRAME_SIDE = 8


@dataclass(frozen=True)
class Region:
    """A rectangle in normalized picture coordinates: origin top-left, x right, y down, 0..1."""

    x: float
    y: float
    width: float
    height: float

    def contains(self, u: float, v: float) -> bool:
        return self.x <= u <= self.x + self.width and self.y <= v <= self.y + self.height

    def pixels(self, width: int, height: int) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) in pixels of a ``width x height`` picture, end exclusive, at least one pixel."""
        x0 = min(width - 1, int(self.x * width))
        y0 = min(height - 1, int(self.y * height))
        x1 = max(x0 + 1, min(width, int(round((self.x + self.width) * width))))
        y1 = max(y0 + 1, min(height, int(round((self.y + self.height) * height))))
        return x0, y0, x1, y1


@dataclass(frozen=True)
class HsvRange:
    """An OpenCV HSV range (hue 0..179, saturation and value 0..255); hue_min > hue_max wraps through red."""

    hue_min: int
    hue_max: int
    saturation_min: int = 80
    saturation_max: int = 255
    value_min: int = 80
    value_max: int = 255


@dataclass(frozen=True)
class FrameScore:
    """One frame's answer: ``hit`` (the object is in the region) and a score in 0..1 with the reason."""

    hit: bool
    score: float
    detail: str


@dataclass(frozen=True)
class Verdict:
    """The monitor's answer: complete once ``streak`` reached the K consecutive hits it needs."""

    complete: bool
    #: The lowest score of the frames in the current streak (0 when there is none).
    score: float
    streak: int
    detail: str


class FrameScorer(Protocol):
    """Scores one BGR frame. Implementations are pure and may be called from any one thread."""

    def score(self, frame: Any) -> FrameScore: ...


def frame_problem(frame: Any) -> str | None:
    """Why ``frame`` cannot be scored (wrong type, shape, dtype or size), None if it can."""
    if not isinstance(frame, np.ndarray):
        return f"the frame is a {type(frame).__name__}, not an image"
    if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
        return f"the frame is {frame.dtype} {tuple(frame.shape)}; the scorer needs height x width x 3 uint8"
    if frame.shape[0] < MIN_FRAME_SIDE or frame.shape[1] < MIN_FRAME_SIDE:
        return f"the frame is {frame.shape[1]}x{frame.shape[0]} pixels, smaller than {MIN_FRAME_SIDE}x{MIN_FRAME_SIDE}"
    return None


@dataclass(frozen=True)
class ColourRegionScorer:
    """Hit when the largest blob of ``colour`` has its centre inside ``region``.

    Why the largest blob's centre: a few stray pixels of the colour (sensor noise,
    a reflection) must neither make a hit nor move the object; the score is the
    share of the blob's pixels inside the region, so a near miss scores below 1.
    ``min_pixels`` is the smallest blob that counts as the object.
    """

    region: Region
    colour: HsvRange
    min_pixels: int = 30

    def score(self, frame: Any) -> FrameScore:
        import cv2

        problem = frame_problem(frame)
        if problem is not None:
            return FrameScore(False, 0.0, problem)
        hsv = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_BGR2HSV)
        c = self.colour
        if c.hue_min <= c.hue_max:
            mask = _in_range(hsv, (c.hue_min, c.saturation_min, c.value_min), (c.hue_max, c.saturation_max, c.value_max))
        else:  # wraps through red (179 -> 0)
            low = _in_range(hsv, (c.hue_min, c.saturation_min, c.value_min), (179, c.saturation_max, c.value_max))
            high = _in_range(hsv, (0, c.saturation_min, c.value_min), (c.hue_max, c.saturation_max, c.value_max))
            mask = cv2.bitwise_or(low, high)
        count, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
        if count <= 1:
            return FrameScore(False, 0.0, "no pixel of the colour in the frame")
        biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        area = int(stats[biggest, cv2.CC_STAT_AREA])
        if area < self.min_pixels:
            return FrameScore(False, 0.0, f"the largest blob of the colour has {area} pixels, under {self.min_pixels}")
        h, w = mask.shape
        cx, cy = (float(v) for v in centroids[biggest])
        x0, y0, x1, y1 = self.region.pixels(w, h)
        inside = int(np.count_nonzero(labels[y0:y1, x0:x1] == biggest))
        share = inside / area
        hit = self.region.contains(cx / w, cy / h)
        where = f"object of {area} px centred at ({cx / w:.3f}, {cy / h:.3f}), {share:.0%} of it in the region"
        return FrameScore(hit, share if hit else min(share, 0.99), where)


def _in_range(hsv: Any, low: tuple[int, int, int], high: tuple[int, int, int]) -> Any:
    import cv2

    return cv2.inRange(hsv, np.array(low, np.uint8), np.array(high, np.uint8))


@dataclass(frozen=True)
class ArucoRegionScorer:
    """Hit when ArUco marker ``marker_id`` (of ``dictionary``) is seen with its centre inside ``region``."""

    region: Region
    marker_id: int
    dictionary: str = "DICT_4X4_50"

    def score(self, frame: Any) -> FrameScore:
        import cv2

        problem = frame_problem(frame)
        if problem is not None:
            return FrameScore(False, 0.0, problem)
        grey = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_BGR2GRAY)
        detector = _aruco_detector(self.dictionary)
        corners, ids, _ = detector.detectMarkers(grey)
        if ids is None:
            return FrameScore(False, 0.0, "no ArUco marker in the frame")
        found = [c for c, i in zip(corners, ids.reshape(-1), strict=True) if int(i) == self.marker_id]
        if not found:
            seen = sorted({int(i) for i in ids.reshape(-1)})[:8]
            return FrameScore(False, 0.0, f"ArUco marker {self.marker_id} not seen (saw {seen})")
        h, w = grey.shape
        centres = [c.reshape(-1, 2).mean(axis=0) for c in found]
        hits = [(float(x) / w, float(y) / h) for x, y in centres if self.region.contains(float(x) / w, float(y) / h)]
        u, v = hits[0] if hits else (float(centres[0][0]) / w, float(centres[0][1]) / h)
        where = f"ArUco marker {self.marker_id} centred at ({u:.3f}, {v:.3f})"
        return FrameScore(bool(hits), 1.0 if hits else 0.5, where + (" in the region" if hits else ", outside the region"))


@functools.lru_cache(maxsize=8)
def _aruco_detector(dictionary: str) -> Any:
    """One detector per dictionary, built once (the monitor's one thread uses it)."""
    import cv2

    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)))


@dataclass(frozen=True)
class Streak:
    """The hits in a row so far and the lowest score among them; ``advance`` returns the next one."""

    needed: int
    hits: int = 0
    low: float = 1.0
    detail: str = "no frame scored yet"

    def advance(self, frame: FrameScore) -> Streak:
        if not frame.hit:
            return Streak(self.needed, 0, 1.0, frame.detail)
        hits = min(self.hits + 1, self.needed)
        return Streak(self.needed, hits, min(self.low, frame.score) if self.hits else frame.score, frame.detail)

    def miss(self, detail: str) -> Streak:
        """A frame that could not be scored (the scorer raised or was too slow) breaks the streak."""
        return Streak(self.needed, 0, 1.0, detail)

    @property
    def verdict(self) -> Verdict:
        complete = self.hits >= self.needed
        return Verdict(complete, self.low if self.hits else 0.0, self.hits, self.detail)
