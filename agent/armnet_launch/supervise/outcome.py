"""Builds the final ``JobResult`` from what was observed about a run.

Pure decision logic, no I/O: the supervisor records facts (exit code, whether
the deadline passed, whether it had to kill, the markers seen) and this module
decides the status and the messages. The rules:

- an infrastructure failure (the job could not start, the engine failed) is
  ``failed`` with ``error`` and no traceback;
- a job still running at its deadline ends ``timeout``, whatever it does in the
  grace window; a return value produced during the grace window is kept;
- a job the host cancelled (Ctrl-C in local mode) ends ``cancelled``;
- otherwise exit code 0 is ``succeeded``; anything else is ``failed``, with
  the ``@main`` traceback when the runtime printed one.
"""

from __future__ import annotations

import signal
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from armnet_core import JobResult, JobStatus


@dataclass(frozen=True)
class RunFacts:
    """Everything observed about one run; ``exit_code`` is None if never known."""

    exit_code: int | None
    timeout_seconds: float
    grace_seconds: float
    deadline_passed: bool = False
    killed_after_grace: bool = False
    cancelled: bool = False
    infra_error: str | None = None
    has_return_value: bool = False
    return_value: Any = None
    traceback: str | None = None
    stdout_tail: str = ""
    stderr_tail: str = ""
    started_at: datetime | None = None
    finished_at: datetime | None = None


# Exit codes of the armnet-runtime entrypoint that are not a raise in @main.
_RUNTIME_EXIT_REASONS = {
    2: "armnet-runtime usage error (see stderr)",
    3: "the script has no @main-decorated function",
    4: "the script failed to import",
    5: "armnet-runtime could not build the job context from the cell's env (see stderr)",
}


def assemble_result(facts: RunFacts) -> JobResult:
    status, error = decide_status(facts)
    return JobResult(
        status=status,
        exit_code=facts.exit_code,
        stdout=facts.stdout_tail,
        stderr=facts.stderr_tail,
        error=error,
        traceback=facts.traceback if facts.infra_error is None else None,
        return_value=facts.return_value if facts.has_return_value else None,
        started_at=facts.started_at,
        finished_at=facts.finished_at,
    )


def decide_status(facts: RunFacts) -> tuple[JobStatus, str | None]:
    """The terminal status and the infra-side ``error`` message (None if none)."""
    if facts.infra_error is not None:
        return JobStatus.FAILED, facts.infra_error
    if facts.cancelled:
        return JobStatus.CANCELLED, "the job was cancelled before it finished"
    if facts.deadline_passed:
        return JobStatus.TIMEOUT, _timeout_message(facts)
    if facts.exit_code == 0:
        return JobStatus.SUCCEEDED, None
    if facts.traceback is not None:
        return JobStatus.FAILED, None
    return JobStatus.FAILED, _exit_message(facts.exit_code)


def _timeout_message(facts: RunFacts) -> str:
    head = f"job exceeded its timeout of {_seconds(facts.timeout_seconds)}"
    if facts.killed_after_grace:
        return f"{head}; killed at the end of the {_seconds(facts.grace_seconds)} grace window"
    return f"{head}; it stopped within the {_seconds(facts.grace_seconds)} grace window"


def _exit_message(exit_code: int | None) -> str:
    if exit_code is None:
        return "the job ended without an exit code"
    if exit_code < 0:
        try:
            name = signal.Signals(-exit_code).name
        except ValueError:
            name = f"signal {-exit_code}"
        return f"the job was killed by {name}"
    if exit_code in _RUNTIME_EXIT_REASONS:
        return f"exit code {exit_code}: {_RUNTIME_EXIT_REASONS[exit_code]}"
    return f"the job exited with code {exit_code}"


def _seconds(value: float) -> str:
    return f"{value:g} s"
