"""Result assembly: which status and message a run's observed facts lead to."""

from __future__ import annotations

import pytest
from armnet_core import JobStatus
from armnet_launch.supervise.outcome import RunFacts, assemble_result

pytestmark = pytest.mark.unit


def facts(**overrides: object) -> RunFacts:
    base: dict[str, object] = {"exit_code": 0, "timeout_seconds": 30.0, "grace_seconds": 5.0}
    base.update(overrides)
    return RunFacts(**base)  # type: ignore[arg-type]


def test_exit_zero_succeeds_with_the_return_value() -> None:
    result = assemble_result(facts(has_return_value=True, return_value={"ok": 1}))
    assert result.status is JobStatus.SUCCEEDED
    assert result.return_value == {"ok": 1}
    assert result.error is None and result.traceback is None


def test_a_raise_in_main_fails_with_its_traceback_and_no_error() -> None:
    result = assemble_result(facts(exit_code=1, traceback="Traceback...\nValueError: boom"))
    assert result.status is JobStatus.FAILED
    assert result.traceback is not None and "ValueError: boom" in result.traceback
    assert result.error is None


def test_a_nonzero_exit_without_traceback_explains_the_runtime_exit_code() -> None:
    result = assemble_result(facts(exit_code=3))
    assert result.status is JobStatus.FAILED
    assert result.error is not None and "no @main" in result.error


def test_a_signal_exit_names_the_signal() -> None:
    result = assemble_result(facts(exit_code=-9))
    assert result.error == "the job was killed by SIGKILL"


def test_a_job_killed_at_grace_end_is_timeout_and_says_so() -> None:
    result = assemble_result(facts(exit_code=-9, deadline_passed=True, killed_after_grace=True))
    assert result.status is JobStatus.TIMEOUT
    assert result.error is not None
    assert "timeout of 30 s" in result.error and "killed at the end of the 5 s grace" in result.error


def test_a_return_value_produced_in_the_grace_window_is_kept_with_status_timeout() -> None:
    result = assemble_result(
        facts(exit_code=0, deadline_passed=True, has_return_value=True, return_value={"steps": 7})
    )
    assert result.status is JobStatus.TIMEOUT
    assert result.return_value == {"steps": 7}
    assert result.error is not None and "stopped within" in result.error


def test_an_infra_failure_is_failed_with_error_and_no_traceback() -> None:
    result = assemble_result(
        facts(exit_code=None, infra_error="no container engine", traceback="ignored")
    )
    assert result.status is JobStatus.FAILED
    assert result.error == "no container engine"
    assert result.traceback is None


def test_cancellation_wins_over_the_deadline() -> None:
    result = assemble_result(facts(exit_code=-9, cancelled=True, deadline_passed=True))
    assert result.status is JobStatus.CANCELLED


def test_no_return_marker_means_no_return_value_even_if_a_value_was_set() -> None:
    result = assemble_result(facts(has_return_value=False, return_value="stale"))
    assert result.return_value is None


def test_tails_and_exit_code_are_carried_over() -> None:
    result = assemble_result(facts(exit_code=0, stdout_tail="a\n", stderr_tail="b\n"))
    assert (result.stdout, result.stderr, result.exit_code) == ("a\n", "b\n", 0)
