"""The supervisor against real child processes: output, deadline, grace, kill."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

import pytest
from armnet_core import JobStatus
from armnet_launch.supervise import JobHooks, SubprocessJob, SupervisorLimits, supervise
from armnet_launch.supervise.observe import EventKind, OutputEvent
from armnet_runtime.markers import format_progress, format_result

pytestmark = pytest.mark.unit


def python_job(code: str) -> SubprocessJob:
    return SubprocessJob.start([sys.executable, "-u", "-c", code], env=dict(os.environ))


def test_output_lines_reach_the_callback_in_order_and_markers_are_parsed() -> None:
    events: list[OutputEvent] = []
    code = (
        f"print('first'); print({format_progress('half way')!r}); "
        f"print({format_result({'n': 2})!r})"
    )
    result = supervise(
        python_job(code), SupervisorLimits(timeout_seconds=30), JobHooks(on_event=events.append)
    )
    assert result.status is JobStatus.SUCCEEDED
    assert result.return_value == {"n": 2}
    assert [e.kind for e in events] == [EventKind.LOG, EventKind.PROGRESS, EventKind.RESULT]
    assert events[1].text == "half way"


def test_a_job_past_its_deadline_gets_the_grace_window_then_is_killed() -> None:
    opened = threading.Event()
    hooks = JobHooks(on_deadline=opened.set)
    result = supervise(
        python_job("import time\nwhile True: time.sleep(0.1)"),
        SupervisorLimits(timeout_seconds=0.5, grace_seconds=0.5),
        hooks,
    )
    assert opened.is_set()
    assert result.status is JobStatus.TIMEOUT
    assert result.error is not None and "killed at the end" in result.error


def test_the_kill_reaches_the_jobs_children_too() -> None:
    code = (
        "import subprocess, sys, time\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        "print(child.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    result = supervise(python_job(code), SupervisorLimits(timeout_seconds=0.5, grace_seconds=0.1))
    child_pid = int(result.stdout.split()[0])
    with pytest.raises(ProcessLookupError):
        for _ in range(50):
            os.kill(child_pid, 0)
            threading.Event().wait(0.05)


def test_cancel_kills_the_job_and_reports_cancelled() -> None:
    hooks = JobHooks()
    hooks.cancel.set()
    result = supervise(python_job("import time; time.sleep(60)"), SupervisorLimits(30), hooks)
    assert result.status is JobStatus.CANCELLED


def test_a_nonzero_exit_is_failed_and_keeps_stderr() -> None:
    result = supervise(
        python_job("import sys; print('bad thing', file=sys.stderr); sys.exit(7)"),
        SupervisorLimits(timeout_seconds=30),
    )
    assert result.status is JobStatus.FAILED
    assert result.exit_code == 7
    assert "bad thing" in result.stderr


def test_a_graceful_cancel_opens_the_grace_window_then_kills_and_ends_cancelled() -> None:
    opened = threading.Event()
    hooks = JobHooks(on_deadline=opened.set)
    hooks.cancel_gracefully.set()
    result = supervise(
        python_job("import time\nwhile True: time.sleep(0.1)"),
        SupervisorLimits(timeout_seconds=60, grace_seconds=0.3),
        hooks,
    )
    assert opened.is_set()
    assert result.status is JobStatus.CANCELLED


def test_a_graceful_cancel_opens_the_grace_window_through_the_cancel_hook_when_the_host_has_one() -> None:
    deadline_opened, cancel_opened = threading.Event(), threading.Event()
    hooks = JobHooks(on_deadline=deadline_opened.set, on_cancel=cancel_opened.set)
    hooks.cancel_gracefully.set()
    result = supervise(
        python_job("import time\nwhile True: time.sleep(0.1)"),
        SupervisorLimits(timeout_seconds=60, grace_seconds=0.3),
        hooks,
    )
    assert cancel_opened.is_set() and not deadline_opened.is_set()
    assert result.status is JobStatus.CANCELLED


def test_a_job_that_stops_within_a_graceful_cancel_keeps_its_return_value() -> None:
    hooks = JobHooks()
    code = f"import time\ntime.sleep(0.3)\nprint({format_result('done')!r})"
    hooks.cancel_gracefully.set()
    result = supervise(python_job(code), SupervisorLimits(timeout_seconds=60, grace_seconds=5), hooks)
    assert result.status is JobStatus.CANCELLED
    assert result.return_value == "done"


def test_an_adopted_job_keeps_the_clock_it_had_before_the_restart() -> None:
    opened = threading.Event()
    result = supervise(
        python_job("import time\nwhile True: time.sleep(0.1)"),
        SupervisorLimits(timeout_seconds=30, grace_seconds=0.2, already_elapsed_s=29.8),
        JobHooks(on_deadline=opened.set),
    )
    assert opened.is_set()
    assert result.status is JobStatus.TIMEOUT


def test_a_result_printed_right_after_a_burst_of_output_is_kept_however_far_behind_the_reader_is() -> None:
    # The job writes 20,000 lines and its result into a 1 MiB pipe and exits at once, while the
    # host is slow to take the first line (a publish that stalls for a few seconds): the
    # reader is far behind at the exit, and the result must still be read, not cut off by a
    # clock started at the exit.
    code = (
        "import fcntl, sys\n"
        "fcntl.fcntl(1, 1031, 1 << 20)  # F_SETPIPE_SZ: the whole burst fits, the job exits at once\n"
        "sys.stdout.write(''.join(f'line {i:05d}\\n' for i in range(20_000)))\n"
        f"sys.stdout.write({format_result('done')!r} + '\\n')\n"
    )
    first = threading.Event()

    def slow_host(event: OutputEvent) -> None:
        if not first.is_set():
            first.set()
            threading.Event().wait(4.0)

    result = supervise(python_job(code), SupervisorLimits(timeout_seconds=60), JobHooks(on_event=slow_host))
    assert result.status is JobStatus.SUCCEEDED
    assert result.return_value == "done"
    assert result.stdout.splitlines()[-2] == "line 19999"


def test_output_held_open_by_a_silent_leftover_process_ends_the_wait_once_no_line_comes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from armnet_launch.supervise import supervisor

    monkeypatch.setattr(supervisor, "DRAIN_STALL_S", 0.5)
    # A child in its own session keeps the job's stdout open, silent, after the job exits.
    code = (
        "import subprocess, sys\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)'], start_new_session=True)\n"
        f"print(child.pid, flush=True)\nprint({format_result('done')!r}, flush=True)\n"
    )
    began = time.monotonic()
    result = supervise(python_job(code), SupervisorLimits(timeout_seconds=60))
    waited = time.monotonic() - began
    os.kill(int(result.stdout.split()[0]), signal.SIGKILL)
    assert result.return_value == "done"
    assert waited < 20, "the supervisor waited for the leftover process (30 s) instead of the output"
