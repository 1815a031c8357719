"""The cell's one device verdict: debounced loss, named devices, HardwareReady, the plugin's health, a job's end."""

from __future__ import annotations

import pytest
from armnet_core import JobStatus
from armnet_node.device_health import (
    DEBOUNCE_S,
    DEVICE_LOST,
    DEVICE_MISSING,
    DeviceState,
    hardware_problem,
    launch_refusal,
    lost_job_error,
    observe,
    stop_message,
)
from armnet_node.deviceplugin.decide import (
    HEALTHY,
    UNHEALTHY,
    DeviceFact,
    DevicePath,
    cell_device_paths,
)

pytestmark = pytest.mark.unit

ARM, CAMERA = cell_device_paths({"follower": "/dev/serial/by-id/usb-arm"}, (0,))


def present(path: DevicePath) -> DeviceFact:
    return DeviceFact(path, "/dev/ttyACM0" if path is ARM else "/dev/video0", True)


def gone(path: DevicePath) -> DeviceFact:
    return DeviceFact(path, None, False)


def healthy_at(t: float) -> DeviceState:
    return observe(DeviceState(), [present(ARM), present(CAMERA)], t)


def vanished(previous: DeviceState, t: float) -> DeviceState:
    return observe(previous, [gone(ARM), present(CAMERA)], t)


def test_every_device_present_is_a_healthy_verdict() -> None:
    state = healthy_at(0.0)
    assert (state.lost, state.problems, state.seen_ok) == (False, (), True)
    assert state.plugin_health == HEALTHY and hardware_problem(state) is None and stop_message(state) is None


def test_a_vanished_device_is_not_lost_before_the_debounce() -> None:
    state = vanished(vanished(healthy_at(0.0), 1.0), 1.0 + DEBOUNCE_S - 0.1)
    assert state.problems and not state.lost
    assert state.plugin_health == HEALTHY and hardware_problem(state) is None and stop_message(state) is None


def test_a_device_missing_for_the_debounce_is_lost_naming_the_arm_and_its_path() -> None:
    state = vanished(vanished(healthy_at(0.0), 1.0), 1.0 + DEBOUNCE_S)
    assert state.lost and state.plugin_health == UNHEALTHY
    reason, message = hardware_problem(state) or ("", "")
    assert reason == DEVICE_LOST
    assert "arm follower's serial port" in message and "/dev/serial/by-id/usb-arm does not exist" in message


def test_a_blink_shorter_than_the_debounce_is_forgotten_and_the_next_spell_starts_its_own_clock() -> None:
    blinked = observe(vanished(healthy_at(0.0), 1.0), [present(ARM), present(CAMERA)], 1.5)
    assert blinked == DeviceState(seen_ok=True)
    again = vanished(blinked, 2.0 + DEBOUNCE_S - 0.5)
    assert again.problems and not again.lost


def test_a_device_missing_from_the_first_read_is_missing_at_once_without_a_debounce() -> None:
    state = observe(DeviceState(), [gone(ARM)], 0.0)
    assert state.lost and not state.seen_ok
    reason, message = hardware_problem(state) or ("", "")
    assert reason == DEVICE_MISSING and "spec.robot.port" in message


def test_a_path_that_is_no_character_device_is_named_as_such() -> None:
    state = observe(healthy_at(0.0), [DeviceFact(CAMERA, "/tmp/video0", False), present(ARM)], 10.0)
    assert state.problems == ("camera 0: /dev/video0 (/tmp/video0) is not a character device",)


def test_a_cell_without_devices_is_never_healthy() -> None:
    state = observe(DeviceState(), [], 0.0)
    assert state.lost and state.plugin_health == UNHEALTHY


def everything_back(previous: DeviceState, t: float) -> DeviceState:
    return observe(previous, [present(ARM), present(CAMERA)], t)


def lost_at(t: float) -> DeviceState:
    return vanished(vanished(healthy_at(0.0), t - DEBOUNCE_S), t)


def test_a_lost_device_that_returns_is_present_at_once_but_the_verdict_holds_until_it_stays() -> None:
    back = everything_back(lost_at(2.5), 3.0)
    assert back.problems == () and back.lost and back.plugin_health == UNHEALTHY
    reason, message = hardware_problem(back) or ("", "")
    assert reason == DEVICE_LOST and "/dev/serial/by-id/usb-arm does not exist" in message


def test_a_lost_verdict_clears_after_the_devices_stayed_present_for_the_debounce() -> None:
    held = everything_back(everything_back(lost_at(2.5), 3.0), 3.0 + DEBOUNCE_S - 0.1)
    assert held.lost
    cleared = everything_back(held, 3.0 + DEBOUNCE_S)
    assert cleared == DeviceState(seen_ok=True) and hardware_problem(cleared) is None


def test_a_flapping_device_keeps_the_lost_verdict_and_its_way_back_starts_over() -> None:
    state = lost_at(2.5)
    for t in (3.0, 4.0, 4.5, 5.5):  # back 1 s, gone, back 1 s, gone: never the debounce present
        state = everything_back(state, t) if t in (3.0, 4.5) else vanished(state, t)
        assert state.lost and hardware_problem(state) is not None
    state = everything_back(state, 6.0)
    assert everything_back(state, 6.0 + DEBOUNCE_S - 0.1).lost
    assert not everything_back(state, 6.0 + DEBOUNCE_S).lost


def test_a_missing_verdict_stays_missing_while_its_device_comes_back() -> None:
    back = everything_back(observe(DeviceState(), [gone(ARM), present(CAMERA)], 0.0), 0.5)
    assert back.lost and (hardware_problem(back) or ("", ""))[0] == DEVICE_MISSING


def test_each_device_has_its_own_debounce_two_short_blinks_of_two_devices_are_no_loss() -> None:
    a, b = cell_device_paths({"a": "/dev/serial/by-id/usb-a", "b": "/dev/serial/by-id/usb-b"})
    up = {a: DeviceFact(a, "/dev/ttyACM0", True), b: DeviceFact(b, "/dev/ttyACM1", True)}
    state = observe(DeviceState(), list(up.values()), 0.0)
    reads = [(0.5, [gone(a), up[b]]), (1.0, [gone(a), gone(b)]), (1.5, [up[a], gone(b)]), (2.0, [up[a], gone(b)])]
    for t, facts in reads:  # a missing 0.5-1.0 s, b missing 1.0-2.0 s: each shorter than the debounce
        state = observe(state, facts, t)
    assert state.problems and not state.lost
    assert observe(state, [up[a], gone(b)], 1.0 + DEBOUNCE_S).lost  # b's own spell ran out


def test_the_stop_message_says_device_lost_and_names_the_device() -> None:
    lost = vanished(vanished(healthy_at(0.0), 1.0), 1.0 + DEBOUNCE_S)
    assert stop_message(lost) == "device lost: arm follower's serial port: /dev/serial/by-id/usb-arm does not exist"


@pytest.mark.parametrize("own", [JobStatus.CANCELLED, JobStatus.FAILED])
def test_a_job_stopped_for_a_lost_device_ends_with_that_error_whatever_it_did_in_grace(own: JobStatus) -> None:
    assert lost_job_error(own, "device lost: arm x", ()) == "device lost: arm x"


@pytest.mark.parametrize("own", [JobStatus.SUCCEEDED, JobStatus.TIMEOUT])
def test_a_job_that_ended_on_its_own_before_the_stop_took_effect_keeps_its_result(own: JobStatus) -> None:
    """Exit 0 (or its timeout) first, the loss recorded while its output drained: the result was earned."""
    assert lost_job_error(own, "device lost: arm x", ()) is None


def test_a_job_that_failed_on_its_own_while_a_device_is_missing_is_failed_for_the_device() -> None:
    assert lost_job_error(JobStatus.FAILED, None, ("arm x: /dev/a does not exist",)) == \
        "device lost: arm x: /dev/a does not exist"


@pytest.mark.parametrize("own", [JobStatus.SUCCEEDED, JobStatus.TIMEOUT, JobStatus.CANCELLED])
def test_a_job_that_ended_otherwise_during_a_blink_keeps_its_result(own: JobStatus) -> None:
    assert lost_job_error(own, None, ("arm x: /dev/a does not exist",)) is None


def test_a_failure_with_every_device_present_keeps_its_own_error() -> None:
    assert lost_job_error(JobStatus.FAILED, None, ()) is None


def test_a_launch_onto_a_lost_device_is_refused_with_the_device_lost_message() -> None:
    assert launch_refusal(lost_at(2.5)) == stop_message(lost_at(2.5))
    assert (launch_refusal(everything_back(lost_at(2.5), 3.0)) or "").startswith("device lost: arm follower")


def test_a_launch_during_a_blink_is_not_refused() -> None:
    assert launch_refusal(vanished(healthy_at(0.0), 1.0)) is None
