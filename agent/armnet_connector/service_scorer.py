"""The ``service`` scorer: an external endpoint (a VLM judge, a team's own model) scores each frame.

The completion monitor calls :meth:`ServiceScorer.score` on its own thread, off the
job's path; this module owns the one HTTP exchange per frame:

- request: ``POST <url>``, body the frame as JPEG (``Content-Type: image/jpeg``), the header
  ``X-Armnet-Camera`` naming the cell camera it comes from;
- answer: ``200`` with a JSON object ``{"score": <number 0..1>, "detail": "<optional text>"}``;
  the frame is a hit when ``score >= threshold`` (the Cell's ``completion.service``).

Anything else — a timeout (``timeoutSeconds``, at most 1 s), a refused connection, another
status, a body that is not that object, an answer larger than ``MAX_ANSWER_BYTES`` —
raises :class:`ServiceScoreError` saying what came back; the monitor counts it
(``completion_scorer_errors``, on the cell's metrics) and answers "not complete" for
that frame. A service is never retried within a frame: the next frame is the retry.
"""

from __future__ import annotations

import json
import math
import urllib.error
import urllib.request
from dataclasses import dataclass
from typing import Any

from armnet_core.cell_completion import ServiceConfig

from .scoring import FrameScore, frame_problem

#: The largest answer read: a score and a short detail are a few dozen bytes.
MAX_ANSWER_BYTES = 64 * 1024
#: How much of a service's ``detail`` (or of an unexpected answer) is kept in a verdict.
DETAIL_CHARS = 200
#: JPEG quality of the frames sent: enough for a judge, a few tens of kB at 640x480.
JPEG_QUALITY = 90


class ServiceScoreError(RuntimeError):
    """The service did not give a score for this frame; the message says what happened instead."""


@dataclass(frozen=True)
class ServiceScorer:
    """Scores a frame by asking ``config.url``; see the module's docstring for the exchange."""

    config: ServiceConfig
    camera: str = ""

    def score(self, frame: Any) -> FrameScore:
        problem = frame_problem(frame)
        if problem is not None:
            return FrameScore(False, 0.0, problem)
        import cv2

        encoded, jpeg = cv2.imencode(".jpg", frame, [int(cv2.IMWRITE_JPEG_QUALITY), JPEG_QUALITY])
        if not encoded:
            raise ServiceScoreError("the frame could not be encoded as JPEG")
        request = urllib.request.Request(
            self.config.url, data=jpeg.tobytes(), method="POST",
            headers={"Content-Type": "image/jpeg", "Accept": "application/json",
                     "X-Armnet-Camera": self.camera[:253]},
        )
        answer = self._ask(request)
        value = parse_answer(answer)
        hit = value >= self.config.threshold
        detail = _detail(answer) or f"the service scored {value:.2f} (threshold {self.config.threshold:g})"
        return FrameScore(hit, value, detail)

    def _ask(self, request: urllib.request.Request) -> Any:
        where = self.config.url[:120]
        try:
            with urllib.request.urlopen(request, timeout=self.config.timeout_seconds) as response:  # noqa: S310 - http(s) only (the config's pattern)
                body = response.read(MAX_ANSWER_BYTES + 1)
        except urllib.error.HTTPError as exc:
            raise ServiceScoreError(f"the scoring service at {where} answered HTTP {exc.code}") from None
        except (urllib.error.URLError, TimeoutError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            raise ServiceScoreError(f"the scoring service at {where} did not answer: {str(reason)[:DETAIL_CHARS]}") \
                from None
        if len(body) > MAX_ANSWER_BYTES:
            raise ServiceScoreError(f"the scoring service at {where} answered more than {MAX_ANSWER_BYTES} bytes")
        try:
            return json.loads(body)
        except ValueError:
            raise ServiceScoreError(
                f"the scoring service at {where} answered no JSON: {body[:80]!r}") from None


def parse_answer(answer: Any) -> float:
    """The score of a service's answer, or ``ServiceScoreError`` saying what the answer lacks."""
    if not isinstance(answer, dict) or "score" not in answer:
        raise ServiceScoreError(f'the scoring service answered {str(answer)[:80]!r}; expected {{"score": 0..1}}')
    value = answer["score"]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) \
            or not 0.0 <= value <= 1.0:
        raise ServiceScoreError(f"the scoring service's score is {str(value)[:40]!r}; expected a number from 0 to 1")
    return float(value)


def _detail(answer: dict[str, Any]) -> str:
    detail = answer.get("detail")
    return detail[:DETAIL_CHARS] if isinstance(detail, str) else ""


__all__ = ["MAX_ANSWER_BYTES", "ServiceScoreError", "ServiceScorer", "parse_answer"]
