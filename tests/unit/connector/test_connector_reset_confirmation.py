"""A reset confirmation reaches only the reset waiting when it arrives."""

from __future__ import annotations

import threading

import pytest
from armnet_connector.inputs import LocalOperatorInputs, feed_lines

pytestmark = pytest.mark.unit


def confirm_when_waiting(inputs: LocalOperatorInputs) -> threading.Thread:
    def confirm() -> None:
        if inputs.wait_reset_pending(10):
            inputs.confirm_reset()

    thread = threading.Thread(target=confirm, daemon=True)
    thread.start()
    return thread


def test_a_confirmation_while_no_reset_waits_is_dropped_and_counted() -> None:
    inputs = LocalOperatorInputs()
    assert inputs.confirm_reset() is False
    assert inputs.ignored_confirmations == 1
    assert inputs.wait_reset_confirmation(0.05) is False


def test_a_confirmation_while_a_reset_waits_confirms_it() -> None:
    inputs = LocalOperatorInputs()
    confirm_when_waiting(inputs)
    assert inputs.wait_reset_confirmation(10) is True


def test_a_second_confirmation_for_the_same_reset_does_not_confirm_the_next() -> None:
    inputs = LocalOperatorInputs()
    confirmed: list[bool] = []

    def confirm_twice() -> None:
        if inputs.wait_reset_pending(10):
            confirmed.extend([inputs.confirm_reset(), inputs.confirm_reset()])

    thread = threading.Thread(target=confirm_twice, daemon=True)
    thread.start()
    assert inputs.wait_reset_confirmation(10) is True
    thread.join(10)
    assert confirmed == [True, False]
    assert inputs.wait_reset_confirmation(0.05) is False


def test_a_reset_that_timed_out_leaves_no_confirmation_for_the_next() -> None:
    inputs = LocalOperatorInputs()
    assert inputs.wait_reset_confirmation(0.01) is False
    assert inputs.confirm_reset() is False
    assert inputs.wait_reset_confirmation(0.05) is False


def test_the_reset_prompt_may_confirm_from_its_callback() -> None:
    inputs = LocalOperatorInputs(on_reset_requested=lambda waiting: waiting.confirm_reset())
    assert inputs.wait_reset_confirmation(1) is True


def test_auto_confirm_still_confirms_every_reset_without_anyone_waiting() -> None:
    inputs = LocalOperatorInputs(auto_confirm_reset=True)
    assert inputs.wait_reset_confirmation(0) is True
    assert inputs.wait_reset_confirmation(0) is True


def test_a_scripted_confirmation_waits_for_the_next_reset_then_confirms_it() -> None:
    inputs = LocalOperatorInputs()
    feeder = threading.Thread(
        target=feed_lines, args=(inputs, ['{"confirm_reset": true}\n', '{"outcome": true}\n']), daemon=True
    )
    feeder.start()
    feeder.join(0.2)
    assert feeder.is_alive(), "the feed waits at its confirmation until a reset waits"
    assert inputs.take_outcome() is None, "lines after the confirmation apply after the reset"
    assert inputs.wait_reset_confirmation(10) is True
    feeder.join(10)
    assert inputs.take_outcome() is True


def waiting_reset(inputs: LocalOperatorInputs, timeout_s: float) -> tuple[threading.Thread, list[bool]]:
    """A reset waiting in another thread (as the connector's ``reset`` op waits); its result lands in the list."""
    result: list[bool] = []
    thread = threading.Thread(target=lambda: result.append(inputs.wait_reset_confirmation(timeout_s)), daemon=True)
    thread.start()
    assert inputs.wait_reset_pending(10)
    return thread, result


def test_each_reset_wait_has_a_number_of_its_own_while_it_waits() -> None:
    inputs = LocalOperatorInputs()
    assert inputs.pending_reset_wait() is None
    assert inputs.wait_reset_confirmation(0.05) is False  # wait number 1, timed out
    assert inputs.pending_reset_wait() is None  # nothing waits
    second, _ = waiting_reset(inputs, 10)
    assert inputs.pending_reset_wait() == 2
    inputs.confirm_reset_wait(2)
    second.join(10)


def test_a_confirmation_naming_the_waiting_reset_confirms_it() -> None:
    inputs = LocalOperatorInputs()
    thread, result = waiting_reset(inputs, 10)
    assert inputs.confirm_reset_wait(1) is True
    thread.join(10)
    assert result == [True]


def test_a_confirmation_naming_an_earlier_reset_wait_is_dropped_and_the_reset_keeps_waiting() -> None:
    inputs = LocalOperatorInputs()
    assert inputs.wait_reset_confirmation(0.05) is False  # wait number 1, timed out
    second, result = waiting_reset(inputs, 10)
    assert inputs.confirm_reset_wait(1) is False
    assert inputs.ignored_confirmations == 1 and inputs.pending_reset_wait() == 2
    inputs.confirm_reset_wait(2)
    second.join(10)
    assert result == [True]
