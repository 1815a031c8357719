"""The cell's automated completion monitor: scores a camera's latest frames in its own thread.

This module owns the thread that, at the cell's configured rate, takes the
newest frame of one camera, scores it (``scoring``) and keeps the verdict that
``is_complete`` on robot.sock answers. It only ever reads frames: it never
touches a bus, never takes a device lock, and takes a camera's frame lock only
to pick up the reference to the newest frame (bounded, as the frame
publisher does), so a job's bus calls and frame reads never wait for it.

A scorer that raises, or that takes longer than ``SLOW_SCORE_S``, is logged and
counted (``Counters.completion_scorer_errors`` / ``completion_scorer_slow``) and
counts as "not complete"; while one score is still running past that limit,
``is_complete`` answers "not complete" at once instead of waiting for it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from armnet_core.backoff import BackoffPolicy
from armnet_core.cell_completion import CompletionConfig

from .classifier_scorer import ClassifierScorer
from .config import CameraConfig
from .inputs import MonitorVerdict, SceneJudgement
from .ratelog import RateLimitedLog
from .scoring import (
    ArucoRegionScorer,
    ColourRegionScorer,
    FrameScorer,
    HsvRange,
    Region,
    Streak,
    Verdict,
)
from .service_scorer import ServiceScorer

log = logging.getLogger(__name__)

SLOW_SCORE_S = 1.0
"""A score that takes longer than this counts as "not complete" (and is counted as slow)."""
FRAME_LOCK_WAIT_S = 0.05
"""How long the monitor waits for a camera's frame lock before skipping one look."""
REOPEN_BACKOFF = BackoffPolicy(first_s=2.0, max_s=8.0)
"""Opening the camera again after an open failed: 2 s after the first, doubling while it keeps failing,
at most 8 s apart (a camera plugged back is scored again within 8 s); a frame read starts over."""
BLOCK_EXTRA_S = 1.0
"""``block=True`` waits at most three scoring periods plus this for a frame newer than the call."""
RECENT_FRAMES = 300
"""Scored frames kept (capture time, hit) for a reset's judgement: at least the most it asks for."""


def block_wait_s(rate_hz: float) -> float:
    """The longest ``is_complete(block=True)`` waits for a frame newer than the call to be scored."""
    return 3.0 / rate_hz + BLOCK_EXTRA_S


def build_scorer(config: CompletionConfig) -> FrameScorer:
    """The scorer a cell's completion settings describe."""
    if config.service is not None:
        return ServiceScorer(config.service, camera=config.camera)
    if config.classifier is not None:
        return ClassifierScorer(config.classifier)
    r = config.region
    assert r is not None  # a region scorer's config holds its region
    region = Region(r.left, r.top, r.width, r.height)
    c = config.colour
    if c is not None:
        colour = HsvRange(c.hue_min, c.hue_max, c.saturation_min, c.saturation_max, c.value_min, c.value_max)
        return ColourRegionScorer(region, colour, config.min_pixels)
    assert config.aruco_id is not None  # the config holds exactly one object
    return ArucoRegionScorer(region, config.aruco_id, config.aruco_dictionary)


@dataclass(frozen=True)
class Frame:
    """A camera's newest frame (BGR) and its capture time on the source's clock."""

    image: Any
    stamp: float


class FrameSource(Protocol):
    """Where the monitor gets frames; ``open``/``latest``/``close`` run on the monitor's thread only."""

    def open(self) -> None: ...
    def latest(self) -> Frame | None: ...
    def clock(self) -> float: ...
    def close(self) -> None: ...


class MonitorCounters(Protocol):
    completion_frames_scored: int
    completion_scorer_errors: int
    completion_scorer_slow: int
    completion_camera_errors: int
    completion_block_timeouts: int


class CameraFrames:
    """The monitor's own camera object on one cell camera, built by the connector's camera factory.

    Why its own object and not the job's: the job may never open the camera, or
    close it mid-episode. On a simulated cell both draw the same scene; on
    hardware a device that allows one reader only is not supported yet
    (docs/connector.md, "Completion monitor").
    """

    def __init__(self, factory: Callable[[str, CameraConfig, Any], Any], name: str, camera: CameraConfig) -> None:
        self._factory = factory
        self.name = name
        self._camera_config = camera
        self._camera: Any = None
        self._rgb = camera.color_mode.lower() == "rgb"

    def open(self) -> None:
        from lerobot.cameras.configs import ColorMode, Cv2Rotation
        from lerobot.cameras.opencv import OpenCVCameraConfig

        c = self._camera_config
        requested = OpenCVCameraConfig(
            index_or_path=c.index_or_path,  # the factory maps a name to the cell's device
            fps=c.fps, width=c.width, height=c.height, color_mode=ColorMode(c.color_mode.lower()),
            rotation=Cv2Rotation(c.rotation), warmup_s=0,
        )
        camera = self._factory(self.name, c, requested)
        camera.connect(warmup=False)
        self._camera = camera

    def latest(self) -> Frame | None:
        import cv2

        camera = self._camera
        if camera is None:
            return None
        lock = camera.frame_lock
        if not lock.acquire(timeout=FRAME_LOCK_WAIT_S):
            return None
        try:  # only the references: cameras store a new array per frame and never draw on a stored one
            image, stamp = camera.latest_frame, camera.latest_timestamp
        finally:
            lock.release()
        if image is None or not isinstance(stamp, float):
            if not camera.is_connected:
                raise ConnectionError(f"camera {self.name} stopped")
            return None
        if self._rgb and getattr(image, "ndim", 0) == 3 and image.shape[2] == 3:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
        return Frame(image, stamp)

    def clock(self) -> float:
        return time.perf_counter()  # LeRobot cameras stamp their frames with it

    def close(self) -> None:
        camera, self._camera = self._camera, None
        if camera is not None and camera.is_connected:
            camera.disconnect()


class CameraCompletionMonitor:
    """Scores ``source``'s newest frame ``config.rate_hz`` times a second; ``is_complete`` reads the verdict."""

    def __init__(
        self, config: CompletionConfig, source: FrameSource, counters: MonitorCounters,
        scorer: FrameScorer | None = None,
    ) -> None:
        self.config = config
        self._source = source
        self._counters = counters
        self._scorer = scorer if scorer is not None else build_scorer(config)
        self._period = 1.0 / config.rate_hz
        self._cond = threading.Condition()
        self._streak = Streak(config.consecutive_frames)
        self._scored_stamp = float("-inf")
        #: Wall-clock time of the latest score (the record's ``frameAt``; the source's clock may be another).
        self._scored_at: float | None = None
        self._scoring_since: float | None = None
        #: (capture stamp, hit, detail) of the latest frames scored (not those a scorer failed on).
        self._recent: deque[tuple[float, bool, str]] = deque(maxlen=RECENT_FRAMES)
        #: The newest frame scored (a reference: cameras never draw on a stored frame), for the rollout's pictures.
        self._scored_image: Any = None
        #: Told each frame scored, on the monitor's thread (the rollouts' pictures); must not block.
        self.on_scored: Callable[[Any], None] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # One rate-limited log per kind of failure: a broken camera must not hide a broken scorer.
        self._warn_scorer = RateLimitedLog(log, interval_s=30.0)
        self._warn_camera = RateLimitedLog(log, interval_s=30.0)
        self._warn_block = RateLimitedLog(log, interval_s=30.0)

    def start(self) -> CameraCompletionMonitor:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="armnet-completion", daemon=True)
        self._thread.start()
        return self

    def stop(self, wait_s: float = 2.0) -> None:
        """Stop scoring; the camera is closed by the thread (a scorer still running keeps it until it returns)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(wait_s)
        with self._cond:
            self._cond.notify_all()

    # -- what the job asks -----------------------------------------------------------

    def verdict(self) -> Verdict:
        """The verdict now; "not complete" while a score runs past ``SLOW_SCORE_S``."""
        with self._cond:
            return self._verdict_locked()

    def is_complete(self, *, block: bool) -> tuple[bool, bool]:
        """(complete, success): a scored completion is a success.

        ``block``: first wait (at most ``block_wait_s``) until a frame captured
        after this call has been scored; if none was, answer "not complete"
        (counted in ``completion_block_timeouts``): a final check must not pass
        on frames older than the episode's end.
        """
        if not block:
            complete = self.verdict().complete
            return complete, complete
        called = self._source.clock()
        with self._cond:
            fresh = self._cond.wait_for(
                lambda: self._scored_stamp > called or self._stop.is_set(), timeout=block_wait_s(self.config.rate_hz)
            )
            if fresh and self._scored_stamp > called:
                complete = self._verdict_locked().complete
                return complete, complete
        self._counters.completion_block_timeouts += 1
        self._warn_block.warning("completion: no frame newer than the call was scored in time; answering not complete")
        return False, False

    def latest_frame(self) -> Any:
        """The newest frame scored (BGR), None before the first: the scene the verdict now rests on."""
        with self._cond:
            return self._scored_image

    def audit(self) -> MonitorVerdict:
        """The verdict now with its score and when its newest frame was scored, for the rollout's record."""
        with self._cond:
            verdict = self._verdict_locked()
            return MonitorVerdict(verdict.complete, verdict.score, self._scored_at)

    def judge_reset(self, frames: int, timeout_s: float) -> SceneJudgement:
        """Whether the scene is back at its start: ``frames`` frames captured after this call scored, none a hit.

        Why every one a miss, not "the streak is not complete": an object half in its
        region (a hit now and then) is not a workspace put back, and the next episode
        would start judged complete. Too few frames scored within ``timeout_s`` (a camera
        down, a scorer failing) is not a reset either.
        """
        frames = max(1, min(frames, RECENT_FRAMES))
        called = self._source.clock()

        def fresh() -> list[tuple[float, bool, str]]:
            return [entry for entry in self._recent if entry[0] > called]

        with self._cond:
            self._cond.wait_for(lambda: len(fresh()) >= frames or self._stop.is_set(), timeout=timeout_s)
            seen = fresh()[:frames]
        hits = sum(1 for _, hit, _ in seen if hit)
        if len(seen) < frames:
            detail = (f"only {len(seen)} of {frames} frames captured after the moves were scored within "
                      f"{timeout_s:g} s (is camera {self.config.camera} delivering frames?)")
            return SceneJudgement(False, len(seen), hits, detail)
        detail = seen[-1][2]
        return SceneJudgement(hits == 0, len(seen), hits, detail)

    def _verdict_locked(self) -> Verdict:
        since = self._scoring_since
        if since is not None and time.monotonic() - since > SLOW_SCORE_S:
            return Verdict(False, 0.0, 0, f"the scorer has been running for over {SLOW_SCORE_S:g} s")
        return self._streak.verdict

    # -- the monitor's thread -----------------------------------------------------------

    def _run(self) -> None:
        opened = False
        reopen = REOPEN_BACKOFF.start()
        try:
            while not self._stop.is_set():
                if not opened:
                    opened = self._open()
                    if not opened:
                        self._stop.wait(reopen.failed())
                        continue
                try:
                    frame = self._source.latest()
                except Exception as exc:  # noqa: BLE001 — a camera failing is reported, then opened again
                    self._camera_failed(exc)
                    opened = False
                    self._close()
                    continue
                reopen.succeeded()
                if frame is not None and frame.stamp > self._scored_stamp:
                    self._score(frame)
                self._stop.wait(self._period)
        finally:
            self._close()

    def _open(self) -> bool:
        try:
            self._source.open()
        except Exception as exc:  # noqa: BLE001 — reported; the monitor answers "not complete" meanwhile
            self._camera_failed(exc)
            self._close()
            return False
        return True

    def _close(self) -> None:
        try:
            self._source.close()
        except Exception as exc:  # noqa: BLE001 — closing a broken camera must not end the monitor
            log.debug("completion camera close failed: %r", exc)

    def _camera_failed(self, exc: BaseException) -> None:
        self._counters.completion_camera_errors += 1
        self._warn_camera.warning(
            "completion monitor: camera %s failed (%s: %s); episodes are not scored until it is back",
            self.config.camera, type(exc).__name__, str(exc)[:200],
        )
        with self._cond:
            self._streak = self._streak.miss("the camera failed")

    def _score(self, frame: Frame) -> None:
        started = time.monotonic()
        with self._cond:
            self._scoring_since = started
        try:
            result = self._scorer.score(frame.image)
            failure = None
        except Exception as exc:  # noqa: BLE001 — a scorer's bug is counted and answers "not complete"
            result, failure = None, f"the scorer raised {type(exc).__name__}: {str(exc)[:200]}"
            self._counters.completion_scorer_errors += 1
            self._warn_scorer.warning("completion monitor: %s", failure)
        took = time.monotonic() - started
        if result is not None and took > SLOW_SCORE_S:
            failure = f"the scorer took {took:.2f} s, over {SLOW_SCORE_S:g} s"
            self._counters.completion_scorer_slow += 1
            self._warn_scorer.warning("completion monitor: %s; counted as not complete", failure)
        with self._cond:
            self._scoring_since = None
            self._streak = self._streak.advance(result) if failure is None and result is not None \
                else self._streak.miss(failure or "")
            if failure is None and result is not None:
                self._recent.append((frame.stamp, result.hit, result.detail))
            self._scored_stamp = frame.stamp
            self._scored_image = frame.image
            self._scored_at = time.time()
            self._counters.completion_frames_scored += 1
            self._cond.notify_all()
        if self.on_scored is not None:
            try:
                self.on_scored(frame.image)
            except Exception as exc:  # noqa: BLE001 — a listener's bug must not stop the scoring
                log.warning("completion monitor: a listener of scored frames failed: %r", exc)
