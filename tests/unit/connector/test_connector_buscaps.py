"""Retry counts and timeouts a job passes are lowered to the connector's caps, wherever passed."""

from __future__ import annotations

import pytest
from armnet_connector.buscaps import (
    MAX_BUS_TIMEOUT_MS,
    MAX_NUM_RETRY,
    cap_call,
    capped_parameters,
)

pytestmark = pytest.mark.unit


def sync_read(data_name, motors=None, *, normalize=True, num_retry=0): ...


def disable_torque(motors=None, num_retry=0): ...


def set_timeout(timeout_ms=None): ...


def test_a_keyword_retry_count_over_the_cap_is_lowered_and_named() -> None:
    capped = cap_call("FeetechMotorsBus", capped_parameters("FeetechMotorsBus", sync_read),
                      ["Present_Position"], {"num_retry": 10**9})
    assert capped.kwargs == {"num_retry": MAX_NUM_RETRY} and capped.lowered == ("num_retry",)


def test_a_positional_retry_count_is_lowered_too() -> None:
    capped = cap_call("FeetechMotorsBus", capped_parameters("FeetechMotorsBus", disable_torque), [None, 10**9], {})
    assert capped.args == [None, MAX_NUM_RETRY]


def test_a_negative_count_and_a_huge_timeout_are_held_within_bounds() -> None:
    params = capped_parameters("FeetechMotorsBus", set_timeout)
    assert cap_call("FeetechMotorsBus", params, [10**12], {}).args == [MAX_BUS_TIMEOUT_MS]
    assert cap_call("FeetechMotorsBus", params, [-5], {}).args == [1]
    retry = capped_parameters("FeetechMotorsBus", sync_read)
    assert cap_call("FeetechMotorsBus", retry, ["x"], {"num_retry": -3}).kwargs == {"num_retry": 0}


def test_values_within_the_caps_and_non_numbers_pass_unchanged() -> None:
    params = capped_parameters("FeetechMotorsBus", sync_read)
    assert cap_call("FeetechMotorsBus", params, ["x"], {"num_retry": 2}).lowered == ()
    assert cap_call("FeetechMotorsBus", params, ["x"], {"num_retry": "many"}).kwargs == {"num_retry": "many"}
    assert cap_call("FeetechMotorsBus", capped_parameters("FeetechMotorsBus", set_timeout), [None], {}).args == [None]


def test_a_method_without_capped_parameters_is_not_inspected_again() -> None:
    def read(data_name, motor): ...

    assert capped_parameters("FeetechMotorsBus", read) == ()
    assert capped_parameters("ARX5Arm", sync_read) == ()
