"""The watch cache keeps our own writes until the watch catches up with them."""

from __future__ import annotations

from typing import Any

import pytest
from armnet_operator.controller import Cache
from armnet_operator.parsing import parse_job

pytestmark = pytest.mark.unit


def body(rv: str, phase: str | None = None) -> dict[str, Any]:
    return {"metadata": {"name": "j", "namespace": "t", "resourceVersion": rv,
                         "creationTimestamp": "2026-01-01T00:00:00Z"},
            "spec": {"embodiment": "lerobot/so-101"}, "status": {"phase": phase} if phase else {}}


def phases(cache: Cache) -> list[tuple[str, str | None]]:
    jobs, _ = cache.snapshot()
    return [(j.resource_version, j.phase) for j in jobs]


def test_a_written_version_shadows_the_older_watched_one() -> None:
    cache = Cache()
    cache.on_job("ADDED", body("5"))
    cache.remember({"t/j": parse_job(body("7", "dispatched"))}, {}, set())
    assert phases(cache) == [("7", "dispatched")]


def test_the_overlay_goes_once_the_watch_delivers_that_version_or_a_later_one() -> None:
    cache = Cache()
    cache.on_job("ADDED", body("5"))
    cache.remember({"t/j": parse_job(body("7", "dispatched"))}, {}, set())
    cache.on_job("MODIFIED", body("6", "queued"))
    assert phases(cache) == [("7", "dispatched")]
    cache.on_job("MODIFIED", body("8", "running"))
    assert phases(cache) == [("8", "running")]


def test_a_deleted_job_leaves_no_overlay_behind() -> None:
    cache = Cache()
    cache.on_job("ADDED", body("5"))
    cache.remember({"t/j": parse_job(body("7", "dispatched"))}, {}, set())
    cache.on_job("DELETED", body("9"))
    assert phases(cache) == []
