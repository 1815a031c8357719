"""The ``service`` scorer: an external endpoint (a VLM judge, a team's own model) scores each frame.

The completion monitor calls :meth:`ServiceScorer.score` on its own thread, off the
job's path; this module owns the one HTTP exchange per frame:

- request: ``POST <url>``, body the frame as JPEG (``Content-Type: image/jpeg``), the header
  ``X-Armnet-Camera`` naming the cell camera it comes from;
- answer: ``200`` with a JSON object ``{"score": <number 0..1>, "detail": "<optional text>"}``;
  the frame is a hit when ``score >= threshold`` (the Cell's ``completion.service``).

With ``tokenFile`` set, each request carries ``Authorization: Bearer <the file's content>``
(surrounding whitespace stripped; at most ``MAX_TOKEN_BYTES``, RFC 6750 token characters
only). The file is read once, at the first frame (``host_files``: a plain file, no link,
no FIFO), and the token never appears in a log, a verdict or an error: a file that is
missing, empty, too large or holds anything but one token is a ``ServiceScoreError``
naming the file, on that frame and every later one of this connector (a fixed file
reaches the next job's connector, as a fixed classifier model does).

Anything else — a timeout (``timeoutSeconds``, at most 1 s), a refused connection, another
status, a body that is not that object, an answer larger than ``MAX_ANSWER_BYTES`` —
raises :class:`ServiceScoreError` saying what came back; the monitor counts it
(``completion_scorer_errors``, on the cell's metrics) and answers "not complete" for
that frame. A service is never retried within a frame: the next frame is the retry.
"""

from __future__ import annotations

import json
import math
import re
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from typing import Any

from armnet_core.cell_completion import ServiceConfig

from .host_files import HostFileError, read_host_file
from .scoring import FrameScore, frame_problem

#: The largest answer read: a score and a short detail are a few dozen bytes.
MAX_ANSWER_BYTES = 64 * 1024
#: How much of a service's ``detail`` (or of an unexpected answer) is kept in a verdict.
DETAIL_CHARS = 200
#: JPEG quality of the frames sent: enough for a judge, a few tens of kB at 640x480.
JPEG_QUALITY = 90
#: The largest token file read: a bearer token is tens to hundreds of bytes.
MAX_TOKEN_BYTES = 8 * 1024


class ServiceScoreError(RuntimeError):
    """The service did not give a score for this frame; the message says what happened instead."""


@dataclass(frozen=True)
class ServiceScorer:
    """Scores a frame by asking ``config.url``; see the module's docstring for the exchange."""

    config: ServiceConfig
    camera: str = ""
    #: The bearer token or why there is none, once read (a one-element list: the scorer is
    #: frozen, its cache is not).
    _token: list[str | ServiceScoreError] = field(default_factory=list, repr=False, compare=False)

    def score(self, frame: Any) -> FrameScore:
        problem = frame_problem(frame)
        if problem is not None:
            return FrameScore(False, 0.0, problem)
        import cv2

        encoded, jpeg = cv2.imencode(".jpg", frame, [int(cv2.IMWRITE_JPEG_QUALITY), JPEG_QUALITY])
        if not encoded:
            raise ServiceScoreError("the frame could not be encoded as JPEG")
        headers = {"Content-Type": "image/jpeg", "Accept": "application/json", "X-Armnet-Camera": self.camera[:253]}
        if self.config.token_file is not None:
            headers["Authorization"] = f"Bearer {self._bearer(self.config.token_file)}"
        request = urllib.request.Request(self.config.url, data=jpeg.tobytes(), method="POST", headers=headers)
        answer = self._ask(request)
        value = parse_answer(answer)
        hit = value >= self.config.threshold
        detail = _detail(answer) or f"the service scored {value:.2f} (threshold {self.config.threshold:g})"
        return FrameScore(hit, value, detail)

    def _bearer(self, path: str) -> str:
        if not self._token:
            try:
                self._token.append(read_token(path))
            except ServiceScoreError as exc:
                self._token.append(exc)
        token = self._token[0]
        if isinstance(token, ServiceScoreError):
            raise ServiceScoreError(str(token))
        return token

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


def read_token(path: str) -> str:
    """The bearer token in ``path`` (whitespace stripped), or ``ServiceScoreError`` naming the file, never its content."""
    try:
        data = read_host_file(path, MAX_TOKEN_BYTES, "the judge's token file")
    except HostFileError as exc:
        raise ServiceScoreError(f"{exc}; put the bearer token there, readable by the connector") from None
    token = data.strip()
    if not _TOKEN.fullmatch(token):
        raise ServiceScoreError(f"the judge's token file {path} holds no bearer token on one line "
                                "(RFC 6750 characters: letters, digits and -._~+/ then any =)")
    return token.decode("ascii")


#: RFC 6750's b64token: what an Authorization header may carry without quoting or encoding.
_TOKEN = re.compile(rb"[A-Za-z0-9\-._~+/]+=*")


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


__all__ = ["MAX_ANSWER_BYTES", "MAX_TOKEN_BYTES", "ServiceScoreError", "ServiceScorer", "parse_answer", "read_token"]
