"""Retrying bus reads that lost their reply, so a loaded machine does not fail a job.

LeRobot waits ~50 ms for a servo's status packet. When the machine is busy, a
reply now and then comes too late ("There is no status packet!", or "Missing
motor IDs" from the ``connect`` handshake). A read changes nothing on the servos,
so the connector may simply ask again: it waits for the late reply to land,
drops it from the port's input buffer (else the next transaction would take it
as its own answer) and repeats the call.

Register writes that wait for an acknowledgement are asked again too: ``write``
(one register of one motor), the torque switches (``enable_torque`` /
``disable_torque``), ``configure_motors`` and a calibration job's ``write_calibration`` /
``reset_calibration`` set absolute values, so a write applied twice leaves the servo
exactly as applied once, and the device lock keeps every other request off the bus
between the attempts. The write's policy check ran once, before the first attempt,
on the same arguments. Loaded hosts failed jobs on "Failed to write 'Torque_Enable'
/ 'Return_Delay_Time' ... no status packet", and a release that gives up early would
leave torque on. ``sync_write`` gets no acknowledgement, so it cannot lose one.

This module owns which calls count as reads, which failures count as a lost
reply (pure functions), and the retry loop. It never decides what a job may call.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

from .reply_window import LATE_REPLY_WAIT_S

log = logging.getLogger(__name__)

_T = TypeVar("_T")


class RetriedDevice(Protocol):
    """What a retry needs of a connection's live object: ``hardware.Handle`` is one.

    A protocol, not ``Handle`` itself: the hardware layer imports the policed bus,
    which imports this module, so naming ``Handle`` here would close a circle.
    """

    class_name: str
    obj: Any


#: How long to wait after a lost reply before asking again (``reply_window``).
RETRY_DELAY_S = LATE_REPLY_WAIT_S
#: The waits before each retry of a read inside a control loop: the first soon (a loop
#: that lost one reply wants its answer), the later ones longer, so a host that starved
#: the connector or the bus for a few hundred milliseconds costs the loop one slow tick,
#: not an exception (seen with three test sessions on two cores: all of two quick
#: retries lost). At most ~0.5 s of waiting in all.
LOOP_RETRY_DELAYS_S = (RETRY_DELAY_S, 0.15, 0.3)
#: Retries after the first attempt, for a read inside a control loop.
MAX_RETRIES = len(LOOP_RETRY_DELAYS_S)
#: The waits before each retry of the ``connect`` handshake: once per job, before any
#: motion, so it can afford to be patient. A connector that the host starved of CPU
#: for a second (a pod's sidecar on a busy node) missed every ping of three quick
#: attempts and failed a job that a second later would have run.
CONNECT_RETRY_DELAYS_S = (RETRY_DELAY_S, 0.25, 0.5, 1.0, 1.0)
#: Both are short fixed lists, not ``armnet_core.backoff``: a bounded number of tries whose first
#: wait is the servo's reply window, inside one request, where the policy's open-ended loops are not.

#: Methods that only read the servos, per allow-listed class.
READ_METHODS: dict[str, frozenset[str]] = {
    "FeetechMotorsBus": frozenset(
        {"sync_read", "read", "ping", "broadcast_ping", "read_calibration", "connect"}
    ),
}
#: Calls that write absolute register values and wait for the servo's acknowledgement:
#: running one again after a lost acknowledgement leaves the servo as running it once.
IDEMPOTENT_CALLS: dict[str, frozenset[str]] = {
    # configure_motors (LeRobot's robots call it in connect): Return_Delay_Time, Maximum_Acceleration
    # and Acceleration set to fixed values, one write each per motor, so all of it may run again.
    # write_calibration and reset_calibration (a calibration job's): Homing_Offset and the position
    # limits set to the values given (or the factory ones), one write each per motor; a loaded host
    # failed a calibration job's write_calibration on a lost acknowledgement. Not
    # set_half_turn_homings: it reads positions that its own first writes have moved.
    "FeetechMotorsBus": frozenset({"write", "enable_torque", "disable_torque", "configure_motors",
                                   "write_calibration", "reset_calibration"}),
}
#: Properties that read the servos when they are read.
READ_PROPERTIES: dict[str, frozenset[str]] = {
    "FeetechMotorsBus": frozenset({"is_calibrated"}),
}
#: The ``connect`` handshake's message when a ping reply was lost.
_HANDSHAKE_MISS = "Missing motor IDs"
#: LeRobot's state errors: ConnectionError subclasses that are no lost reply.
_STATE_ERRORS = frozenset({"DeviceNotConnectedError", "DeviceAlreadyConnectedError"})


def is_read(class_name: str, name: str, *, kind: str) -> bool:
    """Whether calling (``kind="call"``) or reading (``"get"``) ``name`` only reads the servos."""
    table = READ_METHODS if kind == "call" else READ_PROPERTIES
    return name in table.get(class_name, frozenset())


def is_retried(class_name: str, method: str) -> bool:
    """Whether a call of ``method`` that lost a servo reply is asked again: a read, or an absolute write."""
    return (is_read(class_name, method, kind="call")
            or method in IDEMPOTENT_CALLS.get(class_name, frozenset()))


def is_lost_reply(exc: BaseException, *, connecting: bool = False) -> bool:
    """Whether ``exc`` is a servo reply that did not arrive in time (worth asking again)."""
    if type(exc).__name__ in _STATE_ERRORS:
        return False
    if isinstance(exc, (ConnectionError, TimeoutError)):
        return True
    if isinstance(exc, IndexError) and _raised_in_servo_sdk(exc):
        return True  # scservo_sdk indexes a reply cut short by a loaded host instead of reporting it
    return connecting and isinstance(exc, RuntimeError) and _HANDSHAKE_MISS in str(exc)


def _raised_in_servo_sdk(exc: BaseException) -> bool:
    """Whether ``exc`` came from inside ``scservo_sdk`` (its packet parser), not from armnet or LeRobot code."""
    frame = exc.__traceback__
    while frame is not None:
        if "scservo_sdk" in frame.tb_frame.f_code.co_filename:
            return True
        frame = frame.tb_next
    return False


def drop_pending_input(bus: Any) -> None:
    """Discard bytes waiting on the bus's serial port (late replies of the failed attempt)."""
    serial = getattr(getattr(bus, "port_handler", None), "ser", None)
    if serial is not None and getattr(serial, "is_open", False):
        serial.reset_input_buffer()


def _close_half_open(bus: Any) -> None:
    """A failed ``connect`` handshake leaves the port open; close it so ``connect`` may run again."""
    port = getattr(bus, "port_handler", None)
    if port is not None and getattr(port, "is_open", False):
        port.closePort()


def retry_delays(what: str) -> tuple[float, ...]:
    """The waits before each retry of the read ``what`` (its length is the number of retries)."""
    return CONNECT_RETRY_DELAYS_S if what == "connect" else LOOP_RETRY_DELAYS_S


def with_read_retry(
    handle: RetriedDevice,
    what: str,
    call: Callable[[], _T],
    *,
    on_retry: Callable[[], None],
    before_retry: Callable[[], None] | None = None,
    sleep: Callable[[float], None] = time.sleep,
) -> _T:
    """Run the read ``call``; on a lost reply wait, drop stale input and retry (``retry_delays``).

    The caller holds the device lock, so no other request uses the bus between
    attempts. ``on_retry`` is called once per retry (the connector counts them).
    ``before_retry`` runs right before each retry and may raise to end it: the
    connector checks the call again there, so an interlock tripped during the
    wait (a deadline, a cancel, a lost device) holds for a write's retry too.
    """
    if what == "connect" and getattr(handle.obj, "is_connected", False):
        return call()  # already connected: LeRobot raises at once, nothing to retry
    return retry_lost_replies(
        handle.obj, f"{handle.class_name}.{what}", call, connecting=what == "connect",
        on_retry=on_retry, before_retry=before_retry, sleep=sleep,
    )


def retry_lost_replies(
    bus: Any,
    label: str,
    call: Callable[[], _T],
    *,
    on_retry: Callable[[], None],
    connecting: bool = False,
    before_retry: Callable[[], None] | None = None,
    sleep: Callable[[float], None] = time.sleep,
) -> _T:
    """``with_read_retry`` for a bus without a handle: the connector's own reads inside a long call.

    ``label`` names the read in the debug log. A ``connect`` (``connecting``) closes the
    half-open port between attempts; any other read drops the late replies instead.
    """
    delays = CONNECT_RETRY_DELAYS_S if connecting else LOOP_RETRY_DELAYS_S
    for attempt in range(len(delays) + 1):
        try:
            return call()
        except Exception as exc:
            if attempt == len(delays) or not is_lost_reply(exc, connecting=connecting):
                raise
            log.debug("%s lost a reply (%s); retry %d of %d", label,
                      str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__,
                      attempt + 1, len(delays))
            on_retry()
            sleep(delays[attempt])
            if connecting:
                _close_half_open(bus)
            else:
                drop_pending_input(bus)
            if before_retry is not None:
                before_retry()
    raise AssertionError("unreachable")
