"""The ``service`` scorer against a real HTTP server on loopback: what it sends, what it accepts, what it refuses."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from armnet_connector.service_scorer import (
    MAX_ANSWER_BYTES,
    MAX_TOKEN_BYTES,
    ServiceScoreError,
    ServiceScorer,
)
from armnet_core.cell_completion import CompletionConfig, ServiceConfig
from armnet_node.completion_model import files_problem

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


def test_a_judge_with_a_token_file_gets_the_bearer_token_and_it_is_read_once(
    service: ScoringService, tmp_path: Path,
) -> None:
    token = tmp_path / "judge-token"
    token.write_text("s3cr3t-token\n")
    judge = scorer(service.url, tokenFile=str(token))
    judge.score(FRAME)
    token.write_text("rotated")  # read once, at the first frame: the connector of one job keeps it
    judge.score(FRAME)
    assert [headers["Authorization"] for headers, _ in service.received] == ["Bearer s3cr3t-token"] * 2
    assert "s3cr3t" not in repr(judge)


def test_a_token_file_that_is_a_link_or_a_fifo_is_refused_without_reading_or_hanging(
    service: ScoringService, tmp_path: Path,
) -> None:
    import os

    real = tmp_path / "real-token"
    real.write_text("fine")
    link = tmp_path / "judge-token"
    link.symlink_to(real)
    fifo = tmp_path / "fifo-token"
    os.mkfifo(fifo)  # opened blocking, a FIFO nobody writes to would hang the reader for ever
    for path, says in ((link, "is a symbolic link or lies under one"), (fifo, "is not a regular file")):
        with pytest.raises(ServiceScoreError) as raised:
            scorer(service.url, tokenFile=str(path)).score(FRAME)
        assert says in str(raised.value)
    assert not service.received


@pytest.mark.parametrize(("content", "says"), [
    (None, "does not exist on this robot host"),
    (b"", "holds no bearer token on one line"),
    (b"two\nlines", "holds no bearer token on one line"),
    ("t\u00f6ken".encode(), "holds no bearer token on one line"),  # not sendable in a header as it is
    (b"x" * (MAX_TOKEN_BYTES + 1), f"over the {MAX_TOKEN_BYTES:,} bytes it may be"),
])
def test_an_unusable_token_file_is_a_score_error_naming_the_file_never_its_content(
    service: ScoringService, tmp_path: Path, content: bytes | None, says: str,
) -> None:
    token = tmp_path / "judge-token"
    if content is not None:
        token.write_bytes(content)
    with pytest.raises(ServiceScoreError) as raised:
        scorer(service.url, tokenFile=str(token)).score(FRAME)
    assert says in str(raised.value) and str(token) in str(raised.value)
    assert "two" not in str(raised.value) and "lines" not in str(raised.value) and not service.received
    problem = files_problem(CompletionConfig.model_validate(
        {"camera": "front", "scorer": "service", "service": {"url": service.url, "tokenFile": str(token)}}),
        dirs=(str(tmp_path),))
    assert problem is not None and says in problem
