"""One running job's rollout history, fed from two threads and written with its progress.

The connector records rollout begins and ends and its completion monitor's
verdicts (polled here from the job's session); the FMS's verdicts arrive on the NATS bridge's thread. Both go
through :meth:`RolloutRecorder.verdict` / :meth:`sync` under one lock, and the
history itself is decided by the pure ``rollout_history.apply``. A verdict
first catches up with the connector's events, so it lands on the rollout the
bridge saw active even if the once-a-second poll has not seen its begin yet.
The runner writes :meth:`unwritten` with its progress patch and the final
history with the terminal status. A recorder made from a history read back
after an agent restart takes only events later than that history's latest
begin or end: a pod's sidecar gives all its events again.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import Any, Protocol

from armnet_node import rollout_history as rh


class ConnectorRolloutEvent(Protocol):
    """The connector's record of one ``rollout_begin``/``rollout_end`` (``connector.cell.RolloutEvent``)."""

    @property
    def kind(self) -> str: ...

    @property
    def at(self) -> float: ...

    @property
    def index(self) -> int | None: ...

    @property
    def total(self) -> int | None: ...

    @property
    def outcome_controls(self) -> bool | None: ...

    @property
    def success(self) -> bool | None: ...

    @property
    def score(self) -> float | None: ...

    @property
    def frame_at(self) -> float | None: ...


def change_of(event: ConnectorRolloutEvent) -> rh.RolloutChange | None:
    """The history change a connector event means (None for one the history does not record)."""
    at = datetime.fromtimestamp(event.at, UTC)
    if event.kind == "begin" and event.index is not None:
        return rh.Begun(index=event.index, total=event.total or 0, at=at,
                        outcome_controls=event.outcome_controls is not False)
    if event.kind == "end":
        return rh.Ended(at=at)
    if event.kind == "verdict" and event.index is not None and event.success is not None:
        score = event.score if event.score is not None and math.isfinite(event.score) else 0.0
        frame_at = datetime.fromtimestamp(event.frame_at, UTC) if event.frame_at is not None else None
        return rh.Judged(event.index, rh.MonitorMark(event.success, score, at, frame_at))
    return None


class RolloutRecorder:
    """``source`` returns the connector's latest rollout events, oldest first (empty once it stopped)."""

    def __init__(self, source: Callable[[], Sequence[ConnectorRolloutEvent]], history: rh.History = (),
                 clock: Callable[[], datetime] = lambda: datetime.now(UTC),
                 on_overrule: Callable[[], None] | None = None) -> None:
        """``on_overrule`` is called once for each rollout whose operator's outcome came to differ from its monitor's."""
        self._source = source
        self._clock = clock
        self._on_overrule = on_overrule
        self._lock = threading.Lock()
        self._history = history
        #: The rollouts already counted as overruled (a history read back after a restart is not counted again).
        self._overruled = _overruled(history)
        self._written = history
        self._last_seen: Any = None
        #: The latest begin or end the history already holds (read back after an agent restart): a pod's
        #: sidecar outlives the agent and gives its events again from the first; those are not new.
        self._watermark = _latest(history)

    @property
    def history(self) -> rh.History:
        with self._lock:
            return self._history

    def sync(self) -> bool:
        """Take the connector's events not seen yet; True if the history changed."""
        events = list(self._source())
        with self._lock:
            before = self._history
            for event in self._new(events):
                change = change_of(event)
                if change is not None:
                    self._history = rh.apply(self._history, change)
            changed = self._history is not before
        if changed:
            self._count_overrules()
        return changed

    def verdict(self, success: bool, by: str, rollout: int | None) -> None:
        """A cell operator's verdict the bridge passed to the job, recorded on its rollout."""
        self.sync()
        with self._lock:
            self._history = rh.apply(self._history, rh.Marked(success, by, self._clock(), rollout))
        self._count_overrules()

    def overrule(self, success: bool, by: str, rollout: int, started_at: datetime) -> bool:
        """A cell operator's outcome for a rollout the monitor judged (``rollout_history.Overruled``),
        recorded only; False when no rollout of that index and start was judged by the monitor."""
        self.sync()
        with self._lock:
            before = self._history
            self._history = rh.apply(self._history, rh.Overruled(success, by, self._clock(), rollout, started_at))
            changed = self._history is not before
        self._count_overrules()
        return changed

    def _count_overrules(self) -> None:
        with self._lock:
            now = _overruled(self._history)
            new = now - self._overruled
            self._overruled |= now
        if self._on_overrule is not None:
            for _ in new:
                self._on_overrule()

    def accepts_verdict(self, rollout: int | None) -> bool:
        """``rollout_history.accepts_verdict`` on the history caught up with the connector."""
        self.sync()
        with self._lock:
            return rh.accepts_verdict(self._history, rollout)

    def unwritten(self) -> rh.History | None:
        """The history if it changed since :meth:`written` was last told, else None."""
        with self._lock:
            return self._history if self._history != self._written else None

    def written(self, history: rh.History) -> None:
        with self._lock:
            self._written = history

    def _new(self, events: list[ConnectorRolloutEvent]) -> list[ConnectorRolloutEvent]:
        """The events after the last one seen (by identity; by time if it fell out of the connector's window)."""
        if not events:
            return []
        last = self._last_seen
        self._last_seen = events[-1]
        if last is None:
            mark = self._watermark
            return events if mark is None else [e for e in events if _millis(e.at) > mark]
        for position in range(len(events) - 1, -1, -1):
            if events[position] is last:
                return events[position + 1:]
        return [event for event in events if event.at > last.at]


def _overruled(history: rh.History) -> set[tuple[int, datetime]]:
    return {(entry.index, entry.started_at) for entry in history if rh.overruled(entry)}


def _millis(at: float) -> datetime:
    """A connector time as ``status.rollouts`` keeps it (UTC, whole milliseconds)."""
    moment = datetime.fromtimestamp(at, UTC)
    return moment.replace(microsecond=moment.microsecond // 1000 * 1000)


def _latest(history: rh.History) -> datetime | None:
    times = [t for entry in history for t in (entry.started_at, entry.ended_at) if t is not None]
    return max(times) if times else None
