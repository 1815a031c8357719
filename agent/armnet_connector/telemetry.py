"""Servo telemetry and the latest camera frames of a cell, for the cell operator's page.

Two ways, never mixed:

- an idle cell (no job): ``ArmReader`` is the agent's own handle on an arm's
  port, kept open between reads (closed before a launch), doing one
  ``GroupSyncRead`` of the 8 registers from ``Present_Position`` (56) to
  ``Present_Temperature`` (63) per read;
- a job runs: nothing is sent on the bus. ``job_servos`` publishes what the
  connector already recorded of the job's own ``Present_Position`` reads
  (``Handle.present``), so load and temperature are unknown while a job runs.
  Why: a telemetry request on the job's port handle can leave reply bytes in its
  input buffer that the job's next read takes for its answer, and a cut-short
  reply can leave the handle marked busy forever.

Frames are the job's camera objects' latest captures (the same picture the job
sees); nothing here opens a camera a job may open. ``monitor_now`` is the cell's
completion monitor's verdict at this moment (the page shows it live while a rollout runs).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .reply_window import LATE_REPLY_WAIT_S, use_lerobot_reply_window
from .telemetry_decode import (
    TELEMETRY_LENGTH,
    TELEMETRY_START,
    ServoSample,
    decode_block,
    known_positions,
)

if TYPE_CHECKING:
    from .cell import CellState
    from .inputs import MonitorVerdict

log = logging.getLogger(__name__)

BAUD_RATE = 1_000_000


def read_block(port_handler: Any, packet_handler: Any, ids: Iterable[int]) -> dict[int, ServoSample | None]:
    """Servo id -> its sample (None: it did not answer), from one sync read on the agent's own open port.

    A cut-short read leaves the port clean for the next one: the handle is marked
    free again and the unread replies are dropped from the input buffer.
    """
    from scservo_sdk import GroupSyncRead

    serial_port = getattr(port_handler, "ser", None)
    if serial_port is not None:
        serial_port.reset_input_buffer()  # a late reply of the last read is not this read's answer
    wanted = sorted(set(ids))
    group = GroupSyncRead(port_handler, packet_handler, TELEMETRY_START, TELEMETRY_LENGTH)
    for sid in wanted:
        group.addParam(sid)
    try:
        group.txRxPacket()  # stops at the first silent servo; those before it still hold their data
    except (IndexError, OSError) as exc:  # scservo_sdk raises IndexError on a cut-short reply
        log.debug("telemetry sync read failed: %s", exc)
        port_handler.is_using = False  # else every later read is refused as "port busy"
        if serial_port is not None:
            serial_port.reset_input_buffer()
    samples: dict[int, ServoSample | None] = {}
    for sid in wanted:
        raw = group.data_dict.get(sid) or []
        samples[sid] = decode_block(raw) if len(raw) >= TELEMETRY_LENGTH else None
    return samples


class ArmReader:
    """The agent's own handle on an idle arm's port: opened at the first read, kept open until ``close``.

    Its reads give each reply LeRobot's window, and a read asked for soon after a
    cut-short one first waits past that window (``reply_window``): the servos after
    the silent one may still be answering the last read.
    """

    def __init__(self, port: str, protocol: int, *, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.port = port
        self.protocol = protocol
        self._lock = threading.Lock()
        self._handles: tuple[Any, Any] | None = None
        self._clock = clock
        self._sleep = sleep
        self._cut_short_at: float | None = None

    @property
    def is_open(self) -> bool:
        return self._handles is not None

    def read(self, ids: Iterable[int]) -> dict[int, ServoSample | None]:
        """One sync read; OSError when the port cannot be opened (it is retried next read)."""
        with self._lock:
            if self._handles is None:
                self._handles = self._open()
            port_handler, packet_handler = self._handles
            self._wait_out_late_replies()
            try:
                samples = read_block(port_handler, packet_handler, ids)
            except OSError:
                self._close()
                raise
            self._cut_short_at = self._clock() if None in samples.values() else None
            return samples

    def _wait_out_late_replies(self) -> None:
        if self._cut_short_at is not None:
            left = self._cut_short_at + LATE_REPLY_WAIT_S - self._clock()
            if left > 0:
                self._sleep(left)

    def _open(self) -> tuple[Any, Any]:
        from scservo_sdk import PacketHandler, PortHandler

        handler = PortHandler(self.port)
        if not handler.openPort():
            raise OSError(f"cannot open {self.port}")
        handler.setBaudRate(BAUD_RATE)
        use_lerobot_reply_window(handler)
        return handler, PacketHandler(self.protocol)

    def close(self) -> None:
        with self._lock:
            self._close()

    def _close(self) -> None:
        handles, self._handles = self._handles, None
        if handles is not None:
            try:
                handles[0].closePort()
            except OSError as exc:
                log.debug("closing %s: %s", self.port, exc)


def job_servos(cell: CellState) -> dict[str, dict[str, ServoSample | None] | str] | None:
    """arm -> (motor -> last position the job read), or why there is none; None once the job is stopping.

    Reads memory only (no bus traffic, no device lock): what ``Handle.present``
    holds of the job's own reads.
    """
    if cell.stopping.is_set():
        return None
    result: dict[str, dict[str, ServoSample | None] | str] = {}
    for arm_name in cell.config.arms:
        handle = _job_bus(cell, arm_name)
        if handle is None:
            result[arm_name] = "the job has not connected this arm's bus"
            continue
        samples = known_positions(dict(handle.present), handle.cell_motors, handle.cell_ranges)
        result[arm_name] = samples if samples is not None else "the job has not read Present_Position yet"
    return None if cell.stopping.is_set() else result


def _job_bus(cell: CellState, arm_name: str) -> Any:
    for handle in cell.live_handles():
        if handle.class_name == "FeetechMotorsBus" and handle.arm == arm_name:
            return handle
    return None


@dataclass(frozen=True)
class CameraFrame:
    """A camera's newest picture (an HxWx3 uint8 array) and its colour order."""

    image: Any
    bgr: bool = False


def latest_frames(cell: CellState) -> dict[str, CameraFrame]:
    """Camera name -> the newest frame of each camera the job opened (a copy: the job keeps its own)."""
    frames: dict[str, CameraFrame] = {}
    for handle in cell.live_handles():
        if handle.class_name != "OpenCVCamera":
            continue
        name = handle.lock.name.removeprefix("camera:")
        lock = getattr(handle.obj, "frame_lock", None)
        if lock is None:
            continue
        with lock:
            frame = getattr(handle.obj, "latest_frame", None)
        if frame is not None:
            mode = getattr(getattr(handle.obj, "color_mode", None), "value", getattr(handle.obj, "color_mode", ""))
            frames[name] = CameraFrame(frame.copy(), bgr=str(mode).lower() == "bgr")
    return frames


def monitor_now(cell: CellState) -> MonitorVerdict | None:
    """The completion monitor's verdict now (complete, score, when its newest frame was scored); None on a cell
    that scores nothing, and once the job is stopping. Reads the monitor's state only: never a frame or a bus."""
    if cell.stopping.is_set():
        return None
    return cell.completion.audit()
