"""A cell's device verdict from what its device paths show, and what it means for the Cell and a job. Pure.

One verdict per cell, read by everyone who cares whether the cell's devices are
there: the Cell's ``HardwareReady`` condition, the kubelet device plugin's
``ListAndWatch`` health, and the running job (stopped, ending ``failed`` with
"device lost"). The reads (``deviceplugin.facts.read_fact``, every
``POLL_S``) happen in ``node.device_watch``; nothing here does I/O.

**The debounce.** A device that was present and is missing (or is no longer a
character device) is *lost* only once it has stayed so for ``DEBOUNCE_S``
(1.5 s: three reads in a row at the 0.5 s poll). Why: udev re-creates a USB
adapter's ``/dev/serial/by-id`` symlink on a re-enumeration (a USB reset, a
hub's brown-out) and a read may fall between the remove and the add; the job's
open port either survived (the symlink was all that blinked) or the job's own
bus calls fail and say so. Killing a job for a sub-second blink would cost a
whole episode for nothing. Longer than ~2 s is not a blink: a pulled cable
stays pulled, and the job must not wait its whole timeout for it; the stop that
follows honours the grace window as a timeout does. A device missing since the
agent first looked (a wrong path, an arm never plugged in) needs no debounce.
A device that comes back is present again at once (its servos are probed again
on the next heartbeat).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from armnet_core import JobStatus

from armnet_agent.deviceplugin.decide import HEALTHY, UNHEALTHY, DeviceFact, problem

#: Seconds between reads of a cell's device paths.
POLL_S = 0.5
#: Seconds a present device must stay missing before it is lost (see the module docstring).
DEBOUNCE_S = 1.5
#: HardwareReady reasons: the device was present and vanished; it was never seen since the agent started.
DEVICE_LOST = "DeviceLost"
DEVICE_MISSING = "DeviceMissing"
#: Every job error for a lost device begins with this (clients and people search for it).
LOST_PREFIX = "device lost"
NO_DEVICE = "the cell has no device configured (no serial port known)"


@dataclass(frozen=True)
class DeviceState:
    """The verdict on a cell's devices after the reads so far."""

    #: What is wrong now, one line per device, naming it and its path (empty: all present).
    problems: tuple[str, ...] = ()
    #: When (monotonic seconds) the current spell of problems began; None without problems.
    since: float | None = None
    #: The verdict: the problems held for the debounce (or were there from the first read).
    lost: bool = False
    #: Every device was present at some read since the watch began.
    seen_ok: bool = False

    @property
    def plugin_health(self) -> str:
        """What the device plugin tells the kubelet: ``Unhealthy`` exactly when the verdict is lost."""
        return UNHEALTHY if self.lost else HEALTHY


def describe(facts: Sequence[DeviceFact]) -> tuple[str, ...]:
    """What is wrong with the cell's devices now, each line naming the device and its path."""
    if not facts:
        return (NO_DEVICE,)
    return tuple(f"{fact.path.label}: {reason}" for fact in facts if (reason := problem(fact)) is not None)


def observe(previous: DeviceState, facts: Sequence[DeviceFact], now: float, debounce_s: float = DEBOUNCE_S) -> DeviceState:
    """The verdict after one more read of the cell's devices (``now``: monotonic seconds)."""
    problems = describe(facts)
    if not problems:
        return DeviceState(seen_ok=True)
    since = previous.since if previous.problems and previous.since is not None else now
    lost = previous.lost or not previous.seen_ok or now - since >= debounce_s
    return DeviceState(problems, since, lost, previous.seen_ok)


def hardware_problem(state: DeviceState) -> tuple[str, str] | None:
    """``(reason, message)`` of a False ``HardwareReady`` for the devices, or None while they are fine."""
    if not state.lost:
        return None
    listed = "; ".join(state.problems)
    if state.seen_ok:
        return DEVICE_LOST, (f"{listed} (it was present and vanished); plug the device back in (its USB cable, "
                             "its power); HardwareReady turns True when it returns")
    return DEVICE_MISSING, (f"{listed}; plug the device in, or fix the Cell's port (spec.robot.port / "
                            "spec.arms.<arm>.port) or camera path")


def stop_message(state: DeviceState) -> str | None:
    """Why a running job on the cell must stop now, or None while its devices hold."""
    if not state.lost:
        return None
    return f"{LOST_PREFIX}: {'; '.join(state.problems)}"


def lost_job_error(own_status: JobStatus, stopped_for: str | None, problems_now: Sequence[str]) -> str | None:
    """The error of a job whose device went away, or None when its own result stands.

    - stopped for a lost device: ``failed`` with that message, whatever the job did in its
      grace window (its return value and output are kept beside the error);
    - it failed on its own while a device is missing, before the debounce ran out (a real
      unplug makes the job's bus calls fail at once): the missing device is the cause, said so;
    - anything else (a success, a timeout or cancel with every device present) keeps its result.
    """
    if stopped_for is not None:
        return stopped_for
    if own_status is JobStatus.FAILED and problems_now:
        return f"{LOST_PREFIX}: {'; '.join(problems_now)}"
    return None
