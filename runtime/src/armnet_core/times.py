"""RFC 3339 times as the Kubernetes API and armnet's statuses write and read them.

Three precisions, each for a reason, and one reader for all of them:

- :func:`kube_time`: whole seconds, Kubernetes' ``metav1.Time`` (conditions'
  ``lastTransitionTime``, Events' timestamps, a Cell's heartbeat);
- :func:`micro_time`: microseconds, Kubernetes' ``metav1.MicroTime`` (a Lease's
  ``acquireTime``/``renewTime``) and a CellQuota's usage clock, which decays by the
  time between two writes;
- :func:`status_time`: milliseconds, a RobotJob's ``startedAt``/``finishedAt`` and its
  rollouts' times (kill latency and grace windows are measured in them);
- :func:`parse_time`: any of those, or Python's ``isoformat()`` with ``+00:00``, back to
  an aware ``datetime``; ``None`` for what is not a time (a status is tenant-writable input).

Every package formats and parses times here, so a job's ``startedAt`` written by the
node agent reads the same in the operator, the client and the cell operator's page.
"""

from __future__ import annotations

from datetime import datetime, timezone

#: ``datetime.UTC`` is Python 3.11's; the SDK runs on 3.10 too.
_UTC = timezone.utc  # noqa: UP017


def kube_time(moment: datetime) -> str:
    """``2026-11-29T03:20:06Z``: seconds in UTC (``metav1.Time``)."""
    return moment.astimezone(_UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def micro_time(moment: datetime) -> str:
    """``2026-11-29T03:20:06.123456Z``: microseconds in UTC (``metav1.MicroTime``)."""
    return moment.astimezone(_UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def status_time(moment: datetime) -> str:
    """``2026-11-29T03:20:06.123Z``: milliseconds in UTC, for a RobotJob's status and a printed log line.

    ``isoformat``, not ``strftime``: a third of the cost, paid on every line ``armnet logs`` prints.
    """
    if moment.tzinfo is not _UTC:
        moment = moment.astimezone(_UTC)
    return moment.isoformat(timespec="milliseconds")[:-6] + "Z"


def parse_time(value: object) -> datetime | None:
    """An aware ``datetime`` from an RFC 3339 string (``Z`` or an offset), a ``datetime`` as it is;
    ``None`` for anything else, a malformed string included."""
    if isinstance(value, datetime):
        return value
    if not isinstance(value, str) or not value:
        return None
    try:
        moment = datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
    except ValueError:
        return None
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=_UTC)
