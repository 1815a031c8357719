"""Log lines made from a job's status, for when the log stream cannot be read.

Without NATS the client still shows something useful: each new progress
message, each rollout step, the phase changes, and when the job ends the
output tails the agent kept in ``status.result``, then the end with why it
ended (``status.result.error``). The diffing is pure (:func:`changes`,
:func:`ended`); :func:`status_events` only polls.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Optional

from .logwire import CaughtUp, Event, LogLine
from .mapping import result_from_robotjob, status_of
from .resources import RobotJob


def changes(before: Optional[RobotJob], after: RobotJob, *, tails: bool = True) -> list[LogLine]:
    """The lines that tell what changed between two reads of a job (all of it when ``before`` is None).

    ``tails=False`` leaves the output tails out (the caller already showed the output).
    """
    old = before.status if before else None
    new = after.status
    moment = new.finished_at or new.started_at or after.metadata.creation_timestamp
    lines: list[LogLine] = []

    def line(kind: str, text: str, data: object = None) -> None:
        lines.append(LogLine(kind=kind, text=text, time=moment, data=data, source="status"))

    phase = status_of(new.phase).value
    if old is None or status_of(old.phase).value != phase:
        line("status", f"status: {phase}", _status_data(after))
    if new.progress and (old is None or old.progress != new.progress):
        line("progress", new.progress)
    if new.rollout and (old is None or old.rollout != new.rollout):
        line("progress", f"rollout {new.rollout.index}/{new.rollout.total}",
             {"rollout": {"index": new.rollout.index, "total": new.rollout.total}})
    result = result_from_robotjob(after)
    if tails and result is not None and (before is None or result_from_robotjob(before) is None):
        for kind, text in (("stdout", result.stdout), ("stderr", result.stderr)):
            for text_line in text.splitlines():
                line(kind, text_line)
    # The terminal status goes last, after the tails, as the stream's does.
    if result is not None and lines and lines[0].kind == "status":
        lines.append(lines.pop(0))
    return lines


def ended(job: RobotJob) -> Optional[LogLine]:
    """The status line of a finished job, with why it ended as the stream's would say it; None while it runs."""
    result = result_from_robotjob(job)
    if result is None:
        return None
    return LogLine(kind="status", text=f"status: {result.status.value}", time=job.status.finished_at,
                   data=_status_data(job), source="status")


def _status_data(job: RobotJob) -> dict[str, object]:
    """``{"phase", "detail": {"error"}}`` as the agent's status message: the error once the job ended."""
    data: dict[str, object] = {"phase": status_of(job.status.phase).value}
    result = result_from_robotjob(job)
    if result is not None and result.error:
        data["detail"] = {"error": result.error}
    return data


def status_events(
    read: Callable[[], RobotJob], *, follow: bool, interval_s: float, tails: bool = True
) -> Iterator[Event]:
    """Poll ``read`` and yield :func:`changes` until the job is terminal (or once without ``follow``)."""
    before: Optional[RobotJob] = None
    while True:
        job = read()
        yield from changes(before, job, tails=tails)
        if before is None:
            yield CaughtUp()
        before = job
        if not follow or result_from_robotjob(job) is not None:
            return
        time.sleep(interval_s)
