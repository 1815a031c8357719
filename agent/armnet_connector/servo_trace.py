"""The cell's servo trace of a job: what the job's arms were told and where they were, as Parquet.

Why: a robot-learning team debugging a run, and a cell's owner looking into an incident,
need the arm's own record beside the job's data — every position the job read and every
goal it wrote (as the connector let it through, after a clamp), what the connector clamped
and refused, when the interlock tripped, each reset and rollout, and the verdicts (the
monitor's and the person's), each with its time. The Real Robot Challenge keeps such a log
of every run; here the connector writes it into the cell's record of the job
(``record_dir``, a directory the job cannot see), and the node agent uploads it with the
job's output under ``armnet-cell/`` (docs/outputs.md, "The cell's record").

Off the job's path: a bus call appends one tuple to a deque (no conversion, no lock but
the interpreter's); one thread turns what has gathered into a Parquet file every
``PART_S`` seconds (longer as a long job goes on). Parts are numbered (``servo-trace/part-000001.parquet``), each written
under a temporary name and renamed, so a connector that dies loses at most the last few
seconds and never leaves a half-written part; the directory reads as one table
(``pyarrow.parquet.read_table(dir)``, ``pandas.read_parquet(dir)``). Past
``MAX_PENDING`` rows waiting (the writer is behind), or ``MAX_BYTES`` written, rows are dropped
and counted.

Rows (long format, one per motor value or event): ``time`` (UTC, microseconds), ``kind``
(``KINDS``), ``arm``, ``motor``, ``value`` (a position or goal in ``units``, a clamp's
goal as written, a verdict's score), ``units`` (``normalized`` or ``raw``), ``rollout``
(the rollout's index) and ``detail`` (a reason, an outcome).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

from armnet_core.cell_record import SERVO_TRACE

from .record_writer import RecordWriter

log = logging.getLogger(__name__)

#: Seconds between parts in a job's first hour: what a connector that dies can lose at most. The
#: period doubles each hour after (up to 128 s from the seventh), so a day-long job leaves ~4,100
#: parts, well within the uploader's cap on files (``OutputLimits``).
PART_S = 2.0
MAX_PART_DOUBLINGS = 6
#: Bytes of parts one job may write (a day at 100 Hz of two arms is well below); past it rows are dropped.
MAX_BYTES = 1024**3
#: Rows waiting for the writer; past it the newest are dropped (100 Hz of two arms is ~2,400 rows a second).
MAX_PENDING = 200_000
#: How long ``stop`` writes what is still pending (the job has ended: the upload follows).
DRAIN_S = 3.0
#: Seconds between the writer's turns of pending entries into Arrow batches (a part gathers several).
GATHER_S = 1.0
#: Room for events past ``MAX_PENDING``: clamps, trips and verdicts are kept when positions are dropped.
EVENT_ROOM = 10_000
#: A detail longer than this is cut (a refusal's reason; the safety report keeps the whole first ones).
MAX_DETAIL_CHARS = 300
FOLDER = SERVO_TRACE

#: The bus methods whose calls carry positions (``trace_call``).
TRACED_METHODS = frozenset({"sync_read", "sync_write", "write"})
PRESENT = "present_position"
#: The connector's stop (its own ``shutdown`` latch of the interlock): where the job's record ends.
JOB_END = "job_end"
GOAL = "goal_position"
#: Every kind of row, for readers: positions, then the connector's events.
KINDS = (
    PRESENT, GOAL, "clamp", "refusal", "interlock_trip", "reset_begin", "reset_end",
    "rollout_begin", "rollout_end", "monitor_verdict", "operator_verdict", JOB_END,
)


class TraceCounters(Protocol):
    trace_rows_written: int
    trace_rows_dropped: int


class ServoTrace(RecordWriter):
    """``positions``/``event`` from the connector's threads; ``start``/``stop`` with the connector
    (``record_writer``: the stop writes what is pending within its drain time)."""

    thread_name = "armnet-servo-trace"
    default_drain_s = DRAIN_S

    def __init__(self, directory: Path, counters: TraceCounters) -> None:
        """``directory``: the cell's record of the job; the parts go to its ``servo-trace/``."""
        super().__init__()
        self.directory = directory / FOLDER
        self._counters = counters
        #: Tagged tuples: ("p", time, kind, arm, values, normalized) or
        #: ("e", time, kind, arm, motor, value, units, rollout, detail).
        self._pending: deque[tuple[Any, ...]] = deque()
        self._dropped = 0
        self._drop_lock = threading.Lock()
        #: What the writer gathered since the last part: Arrow batches, one per ``GATHER_S``.
        self._batches: list[Any] = []
        self._parts = 0
        self._bytes = 0
        self._full = False

    # -- the connector's threads ---------------------------------------------------------

    def positions(self, kind: str, arm: str, values: Mapping[str, Any], normalized: bool) -> None:
        """The job read (``PRESENT``) or wrote (``GOAL``) these motor values on ``arm``: one row each."""
        if len(self._pending) >= MAX_PENDING:
            self._drop(len(values))
            return
        self._pending.append(("p", time.time(), kind, arm, values, normalized))

    def event(
        self, kind: str, *, arm: str | None = None, motor: str | None = None, value: float | None = None,
        units: str | None = None, rollout: int | None = None, detail: str | None = None,
    ) -> None:
        """One event of the connector's (a clamp, a trip, a reset, a rollout, a verdict).

        Events have room of their own past ``MAX_PENDING`` (``EVENT_ROOM``): a job flooding the
        bus does not push its clamps and trips out of the trace.
        """
        if len(self._pending) >= MAX_PENDING + EVENT_ROOM:
            self._drop(1)
            return
        if detail is not None and len(detail) > MAX_DETAIL_CHARS:
            detail = detail[:MAX_DETAIL_CHARS]
        self._pending.append(("e", time.time(), kind, arm, motor, value, units, rollout, detail))

    def _drop(self, rows: int) -> None:
        with self._drop_lock:
            self._dropped += rows

    # -- the writer's thread --------------------------------------------------------------

    def _run(self) -> None:
        # Arrow's first array imports pandas (seconds on a loaded host; in a connector LeRobot's modules
        # usually have): here, at the start, off the job's path, not at the first part.
        _batch(_columns([]))
        started = last_part = time.monotonic()
        while not self.closing.wait(GATHER_S):
            self._gather()  # small steps: the conversion never holds the interpreter for long
            if time.monotonic() - last_part >= part_period_s(time.monotonic() - started):
                self._write_part()
                last_part = time.monotonic()
        self._gather()
        self._write_part()  # the stop: what the job's last calls left

    def _gather(self) -> None:
        """Turn what is pending into an Arrow batch (kept until the next part)."""
        pending = self._pending
        items = [pending.popleft() for _ in range(len(pending))]
        with self._drop_lock:
            dropped, self._dropped = self._dropped, 0
        if dropped:
            self._counters.trace_rows_dropped += dropped
            log.warning("servo trace: %d rows not kept (the writer was behind)", dropped)
        if not items:
            return
        try:
            self._batches.append(_batch(_columns(items)))
        except Exception as exc:  # noqa: BLE001 — rows lost are counted; the trace goes on
            self._counters.trace_rows_dropped += len(items)
            log.warning("servo trace: %d entries not kept: %s: %s", len(items), type(exc).__name__, str(exc)[:200])

    def _write_part(self) -> None:
        batches, self._batches = self._batches, []
        rows = sum(batch.num_rows for batch in batches)
        if not rows:
            return
        if self._bytes >= MAX_BYTES:
            self._counters.trace_rows_dropped += rows
            if not self._full:
                self._full = True
                log.warning("servo trace: %d bytes written, the most one job keeps; later rows are counted, "
                            "not kept", self._bytes)
            return
        try:
            self._parts += 1
            self._bytes += self._write_table(batches, self._parts)
        except Exception as exc:  # noqa: BLE001 — a part lost is counted; the job goes on
            self._counters.trace_rows_dropped += rows
            log.warning("servo trace: part %d (%d rows) not kept: %s: %s", self._parts, rows,
                        type(exc).__name__, str(exc)[:200])
            return
        self._counters.trace_rows_written += rows

    def _write_table(self, batches: list[Any], number: int) -> int:
        """Write part ``number``; its size in bytes."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.directory.mkdir(parents=True, exist_ok=True)
        name = f"part-{number:06d}.parquet"
        partial = self.directory / f".{name}.partial"
        pq.write_table(pa.Table.from_batches(batches), partial, compression="zstd")
        size = partial.stat().st_size
        os.replace(partial, self.directory / name)  # the upload never takes a half-written part
        return size


def part_period_s(running_s: float) -> float:
    """Seconds to the next part of a job that has run ``running_s``: ``PART_S``, doubled each hour after the first."""
    return PART_S * float(2 ** min(int(running_s // 3600), MAX_PART_DOUBLINGS))


def _columns(items: list[tuple[Any, ...]]) -> dict[str, list[Any]]:
    """The rows of ``items`` as columns; a value that is not a finite-or-not number is kept as None."""
    names = ("time", "kind", "arm", "motor", "value", "units", "rollout", "detail")
    columns: dict[str, list[Any]] = {name: [] for name in names}
    time_, kind_, arm_, motor_, value_, units_, rollout_, detail_ = (columns[n] for n in names)
    for item in items:
        if item[0] == "p":
            _tag, at, kind, arm, values, normalized = item
            units = _units(normalized)
            stamp = int(at * 1e6)
            for motor, value in values.items():
                time_.append(stamp)
                kind_.append(kind)
                arm_.append(arm)
                motor_.append(str(motor))
                value_.append(_number(value))
                units_.append(units)
                rollout_.append(None)
                detail_.append(None)
        else:
            _tag, at, kind, arm, motor, value, units, rollout, detail = item
            time_.append(int(at * 1e6))
            kind_.append(kind)
            arm_.append(arm)
            motor_.append(motor)
            value_.append(_number(value))
            units_.append(units)
            rollout_.append(rollout)
            detail_.append(detail)
    return columns


def _batch(columns: dict[str, list[Any]]) -> Any:
    """The columns as an Arrow record batch of the trace's schema."""
    import pyarrow as pa

    return pa.RecordBatch.from_arrays([pa.array(columns[name], kind) for name, kind in _schema()],
                                      names=[name for name, _kind in _schema()])


def _schema() -> list[tuple[str, Any]]:
    import pyarrow as pa

    return [("time", pa.timestamp("us", tz="UTC")), ("kind", pa.string()), ("arm", pa.string()),
            ("motor", pa.string()), ("value", pa.float64()), ("units", pa.string()), ("rollout", pa.int64()),
            ("detail", pa.string())]


def _units(normalized: bool) -> str:
    return "normalized" if normalized else "raw"


def _number(value: Any) -> float | None:
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def trace_call(trace: ServoTrace, arm: str, method: str, args: list[Any], kwargs: dict[str, Any], result: Any) -> None:
    """The positions in a job's bus call that went through: a ``Present_Position`` read, a ``Goal_Position`` write.

    LeRobot's signatures: ``sync_read(data_name, motors=None, *, normalize=True, ...)``,
    ``sync_write(data_name, values, *, normalize=True, ...)``, ``write(data_name, motor,
    value, *, normalize=True, ...)``. The values of a write are the ones the bus sent (a
    clamped goal as clamped: the motion guard rewrote the arguments before the call).
    """
    data_name = args[0] if args else kwargs.get("data_name")
    normalized = bool(kwargs.get("normalize", True))
    if method == "sync_read":
        if data_name == "Present_Position" and isinstance(result, dict):
            trace.positions(PRESENT, arm, result, normalized)
    elif data_name == "Goal_Position":
        if method == "sync_write":
            values = args[1] if len(args) > 1 else kwargs.get("values")
            if isinstance(values, dict):
                trace.positions(GOAL, arm, values, normalized)
            elif values is not None:
                trace.event(GOAL, arm=arm, motor=None, value=_number(values), units=_units(normalized),
                            detail="every motor")
        elif method == "write":
            motor = args[1] if len(args) > 1 else kwargs.get("motor")
            value = args[2] if len(args) > 2 else kwargs.get("value")
            if isinstance(motor, str):
                trace.positions(GOAL, arm, {motor: value}, normalized)
