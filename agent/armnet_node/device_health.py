"""A cell's device verdict from what its device paths show, and what it means for the Cell and a job. Pure.

One verdict per cell, read by everyone who cares whether the cell's devices are
there: the Cell's ``HardwareReady`` condition, the kubelet device plugin's
``ListAndWatch`` health, and the running job (stopped, ending ``failed`` with
"device lost"). The reads (``deviceplugin.facts.read_fact``, every
``POLL_S``) happen in ``node.device_watch``; nothing here does I/O.

**The debounce.** A device that was present and is missing (or is no longer a
character device) is *lost* only once it has stayed so for ``DEBOUNCE_S``
(1.5 s). At the 0.5 s poll that is four reads in a row: the first read that
finds it missing starts its clock (``since``), and the read at ``since + 1.5 s``
is the first that finds the debounce run out. Each device has its own clock:
arm A missing for 0.5 s and arm B for 1 s a little later are two blinks, not
one loss. Why a debounce: udev re-creates a USB adapter's ``/dev/serial/by-id``
symlink on a re-enumeration (a USB reset, a hub's brown-out) and a read may
fall between the remove and the add; the job's open port either survived (the
symlink was all that blinked) or the job's own bus calls fail and say so.
Killing a job for a sub-second blink would cost a whole episode for nothing.
Longer than ~2 s is not a blink: a pulled cable stays pulled, and the job must
not wait its whole timeout for it; the stop that follows honours the grace
window as a timeout does. A device missing since the agent first looked (a
wrong path, an arm never plugged in) needs no debounce.

**The way back.** A lost verdict clears only once every device has stayed
present for ``DEBOUNCE_S`` (the same four reads): a flaky cable that comes and
goes must not turn ``HardwareReady`` True between two drops, or the operator
binds a job that the next drop fails. While the devices are back but the
verdict holds, ``problems`` is empty (the bus may be probed again) and the
verdict keeps naming what was lost (``lost_problems``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from armnet_core import JobStatus

from armnet_node.deviceplugin.decide import HEALTHY, UNHEALTHY, DeviceFact, problem

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
    #: Each missing device (its container path; ``""``: no device configured) and when
    #: (monotonic seconds) its current spell began: every device has its own debounce.
    missing_since: tuple[tuple[str, float], ...] = ()
    #: The verdict: a device's problem held for the debounce (or was there from the first read),
    #: and the devices have not yet stayed present for the debounce since.
    lost: bool = False
    #: Every device was present at some read since the watch began (a missing verdict: once it cleared).
    seen_ok: bool = False
    #: What the lost verdict names: the problems when it was last seen with any (kept while they are back).
    lost_problems: tuple[str, ...] = ()
    #: While lost with every device present: when (monotonic seconds) they all came back.
    back_since: float | None = None

    @property
    def plugin_health(self) -> str:
        """What the device plugin tells the kubelet: ``Unhealthy`` exactly when the verdict is lost."""
        return UNHEALTHY if self.lost else HEALTHY


def _problems_by_device(facts: Sequence[DeviceFact]) -> dict[str, str]:
    """Device (its container path) -> what is wrong with it now, for the devices with a problem."""
    if not facts:
        return {"": NO_DEVICE}
    return {fact.path.container_path: f"{fact.path.label}: {reason}"
            for fact in facts if (reason := problem(fact)) is not None}


def describe(facts: Sequence[DeviceFact]) -> tuple[str, ...]:
    """What is wrong with the cell's devices now, each line naming the device and its path."""
    return tuple(_problems_by_device(facts).values())


def observe(previous: DeviceState, facts: Sequence[DeviceFact], now: float, debounce_s: float = DEBOUNCE_S) -> DeviceState:
    """The verdict after one more read of the cell's devices (``now``: monotonic seconds)."""
    wrong = _problems_by_device(facts)
    if not wrong:
        if not previous.lost:
            return DeviceState(seen_ok=True)
        back = previous.back_since if previous.back_since is not None else now
        if now - back >= debounce_s:
            return DeviceState(seen_ok=True)
        return DeviceState(lost=True, seen_ok=previous.seen_ok, lost_problems=previous.lost_problems, back_since=back)
    problems = tuple(wrong.values())
    earlier = dict(previous.missing_since)
    since = tuple((device, earlier.get(device, now)) for device in wrong)
    lost = previous.lost or not previous.seen_ok or any(now - began >= debounce_s for _, began in since)
    return DeviceState(problems, since, lost, previous.seen_ok, problems if lost else ())


def hardware_problem(state: DeviceState) -> tuple[str, str] | None:
    """``(reason, message)`` of a False ``HardwareReady`` for the devices, or None while they are fine."""
    if not state.lost:
        return None
    listed = "; ".join(state.lost_problems)
    if state.seen_ok:
        return DEVICE_LOST, (f"{listed} (it was present and vanished); plug the device back in (its USB cable, "
                             f"its power); HardwareReady turns True once it has stayed back for {DEBOUNCE_S:g} s")
    return DEVICE_MISSING, (f"{listed}; plug the device in, or fix the Cell's port (spec.robot.port / "
                            "spec.arms.<arm>.port) or camera path")


def stop_message(state: DeviceState) -> str | None:
    """Why a running job on the cell must stop now, or None while its devices hold."""
    if not state.lost:
        return None
    return f"{LOST_PREFIX}: {'; '.join(state.lost_problems)}"


def launch_refusal(state: DeviceState) -> str | None:
    """Why a job must not launch on the cell now (it fails before anything starts), or None.

    The lost verdict, the same message a running job is stopped with: a launch onto a lost
    device would only run into its grace window and fail there.
    """
    return stop_message(state)


def lost_job_error(own_status: JobStatus, stopped_for: str | None, problems_now: Sequence[str]) -> str | None:
    """The error of a job whose device went away, or None when its own result stands.

    - stopped for a lost device and the stop took effect (the job ended cancelled, or failed):
      ``failed`` with that message, whatever the job did in its grace window (its return value
      and output are kept beside the error); a job that exited on its own first (succeeded, or
      timed out) keeps its result, even if the loss was recorded while its output drained;
    - it failed on its own while a device is missing, before the debounce ran out (a real
      unplug makes the job's bus calls fail at once): the missing device is the cause, said so;
    - anything else (a success, a timeout or cancel with every device present) keeps its result.
    """
    if stopped_for is not None and own_status in (JobStatus.CANCELLED, JobStatus.FAILED):
        return stopped_for
    if own_status is JobStatus.FAILED and problems_now:
        return f"{LOST_PREFIX}: {'; '.join(problems_now)}"
    return None
