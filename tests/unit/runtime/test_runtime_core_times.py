"""armnet_core.times: the three precisions every package writes, and the one reader."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest
from armnet_core.times import kube_time, micro_time, parse_time, status_time

MOMENT = datetime(2026, 11, 29, 3, 20, 6, 123456, tzinfo=timezone.utc)  # noqa: UP017


def test_each_precision_is_written_in_utc_with_a_z() -> None:
    assert kube_time(MOMENT) == "2026-11-29T03:20:06Z"
    assert micro_time(MOMENT) == "2026-11-29T03:20:06.123456Z"
    assert status_time(MOMENT) == "2026-11-29T03:20:06.123Z"
    # Another zone is converted, not relabelled.
    assert kube_time(MOMENT.astimezone(timezone(timedelta(hours=-5)))) == "2026-11-29T03:20:06Z"


@pytest.mark.parametrize("write", [kube_time, micro_time, status_time])
def test_what_is_written_reads_back_aware_and_to_its_precision(write) -> None:  # type: ignore[no-untyped-def]
    moment = parse_time(write(MOMENT))
    assert moment is not None and moment.tzinfo is not None
    assert abs((moment - MOMENT).total_seconds()) < 1


def test_isoformat_and_an_offset_read_as_the_same_moment() -> None:
    assert parse_time(MOMENT.isoformat()) == MOMENT
    assert parse_time("2026-11-29T04:20:06.123456+01:00") == MOMENT
    assert parse_time(MOMENT) is MOMENT


@pytest.mark.parametrize("value", [None, "", "yesterday", "2026-13-01T00:00:00Z", 1732850406, ["2026"]])
def test_what_is_not_a_time_reads_as_none(value: object) -> None:
    assert parse_time(value) is None


def test_a_time_without_a_zone_is_taken_as_utc() -> None:
    assert parse_time("2026-11-29T03:20:06") == MOMENT.replace(microsecond=0)
