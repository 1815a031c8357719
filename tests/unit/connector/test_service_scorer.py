"""The ``service`` scorer against a real HTTP server on loopback: what it sends, what it accepts, what it refuses."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from armnet_connector.service_scorer import MAX_ANSWER_BYTES, ServiceScoreError, ServiceScorer
from armnet_core.cell_completion import ServiceConfig

from tests.support.scoring_service import ScoringService

pytestmark = pytest.mark.unit

@pytest.fixture
def service() -> Iterator[ScoringService]:
    running = ScoringService(lambda _headers, _body: (200, b'{"score": 1}'))
    yield running
    running.close()


def scorer(url: str, **settings: Any) -> ServiceScorer:
    return ServiceScorer(ServiceConfig.model_validate({"url": url, **settings}), camera="front")


FRAME = np.zeros((48, 64, 3), dtype=np.uint8)
FRAME[10:20, 30:40] = (0, 0, 255)  # a red square (BGR)


def test_a_frame_goes_out_as_jpeg_naming_its_camera_and_the_answer_is_the_score(service: ScoringService) -> None:
    import cv2

    service.answer = lambda _h, _b: (200, b'{"score": 0.8, "detail": "cube on the pad"}')
    result = scorer(service.url).score(FRAME)
    assert (result.hit, result.score, result.detail) == (True, 0.8, "cube on the pad")
    headers, body = service.received[0]
    assert headers["Content-Type"] == "image/jpeg" and headers["X-Armnet-Camera"] == "front"
    sent = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
    assert sent.shape == FRAME.shape and sent[15, 35, 2] > 200  # the red square arrived


def test_a_score_under_the_threshold_is_a_miss(service: ScoringService) -> None:
    service.answer = lambda _h, _b: (200, b'{"score": 0.6}')
    result = scorer(service.url, threshold=0.75).score(FRAME)
    assert (result.hit, result.score) == (False, 0.6)
    assert "0.60 (threshold 0.75)" in result.detail


@pytest.mark.parametrize(("status", "body", "says"), [
    (500, b'{"error": "model not loaded"}', "answered HTTP 500"),
    (200, b"<html>busy</html>", "answered no JSON"),
    (200, b'{"complete": true}', 'expected {"score": 0..1}'),
    (200, b'{"score": 1.5}', "expected a number from 0 to 1"),
    (200, b'{"score": true}', "expected a number from 0 to 1"),
    (200, b'{"score": NaN}', "expected a number from 0 to 1"),
    (200, b'[0.9]', 'expected {"score": 0..1}'),
    (200, b'{"score": 0.9, "pad": "' + b"x" * MAX_ANSWER_BYTES + b'"}', f"more than {MAX_ANSWER_BYTES} bytes"),
])
def test_an_answer_that_is_not_a_score_is_an_error_saying_what_came_back(
        service: ScoringService, status: int, body: bytes, says: str) -> None:
    service.answer = lambda _h, _b: (status, body)
    with pytest.raises(ServiceScoreError, match="scoring service") as raised:
        scorer(service.url).score(FRAME)
    assert says in str(raised.value)


def test_a_service_slower_than_its_timeout_is_an_error_not_a_wait(service: ScoringService) -> None:
    def slow(_headers: dict[str, str], _body: bytes) -> tuple[int, bytes]:
        service.release.wait(30)
        return 200, b'{"score": 1}'

    service.answer = slow
    with pytest.raises(ServiceScoreError, match="did not answer"):
        scorer(service.url, timeoutSeconds=0.1).score(FRAME)


def test_a_service_that_is_down_is_an_error() -> None:
    down = ScoringService(lambda _headers, _body: (200, b'{"score": 1}'))
    url = down.url
    down.close()  # nothing listens on its port any more
    with pytest.raises(ServiceScoreError, match="did not answer"):
        scorer(url).score(FRAME)


def test_a_frame_that_is_no_image_is_a_miss_and_never_sent(service: ScoringService) -> None:
    result = scorer(service.url).score(np.zeros((4, 4), dtype=np.uint8))
    assert not result.hit and "the scorer needs height x width x 3 uint8" in result.detail
    assert service.received == []
