"""When a waiting RobotJob will start at the latest. Pure.

The bound is the one a batch scheduler gives from time limits (Slurm's expected
start): every running job and every job ahead in the queue is assumed to use its
whole ``timeoutSeconds`` plus its cell's grace period, and each waiting job, in
queue order, takes the matching cell that frees first. A job that ends early only
makes the start earlier, so the time is a promise the queue can keep, not a guess.

Only jobs that wait for busy cells get one: a job waiting for its quota, for a cell
that is offline, faulted or cordoned, or for a cell that does not exist has no
bound in time (it waits on a person).

Cost: one heap per cell pool (embodiment, and embodiment with task), so each waiting
job costs O(log cells) amortised, like the scheduling pass it follows.
"""

from __future__ import annotations

import heapq
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timedelta

from .model import Cell, Job

_PoolKey = tuple[str, str | None] | str


@dataclass(frozen=True)
class Seat:
    """A cell that can run the queue's jobs, and when it is free at the latest."""

    cell: Cell
    free_at: datetime


def seats(cells: Iterable[Cell], holders: Mapping[str, Job], now: datetime) -> list[Seat]:
    """Each available cell with the latest moment its job (``holders``, by cell name) leaves it.

    A job that has started leaves at its start plus timeout plus grace; one bound but
    not started yet at its binding plus the same (it starts at once on a ready cell).
    A job past that moment is already overdue: the cell is counted free now.
    """
    result = []
    for cell in cells:
        job = holders.get(cell.name)
        if job is None:
            result.append(Seat(cell, now))
            continue
        since = job.started_at or job.bound_at or now
        result.append(Seat(cell, max(now, since + occupancy(job, cell))))
    return result


def occupancy(job: Job, cell: Cell) -> timedelta:
    """The longest a job holds a cell: its timeout, then the cell's grace period."""
    return timedelta(seconds=job.timeout_seconds) + cell.grace_period


def latest_starts(queue: Iterable[Job], available: Iterable[Seat]) -> dict[str, datetime]:
    """Job key -> the latest moment it starts, for ``queue`` in its order (the first starts first).

    A job with a task draws from the cells of its (embodiment, task); one without, from
    every cell of its embodiment. A job no seat matches gets no entry.
    """
    free_at: dict[str, datetime] = {}
    version: dict[str, int] = defaultdict(int)
    cells: dict[str, Cell] = {}
    heaps: dict[_PoolKey, list[tuple[datetime, str, int]]] = defaultdict(list)
    for seat in available:
        name = seat.cell.name
        cells[name], free_at[name] = seat.cell, seat.free_at
        for key in _pools(seat.cell):
            heaps[key].append((seat.free_at, name, 0))
    for entries in heaps.values():
        heapq.heapify(entries)

    starts: dict[str, datetime] = {}
    for job in queue:
        heap = heaps.get(job.embodiment if job.task is None else (job.embodiment, job.task))
        while heap and heap[0][2] != version[heap[0][1]]:
            heapq.heappop(heap)  # an entry from before the cell was taken again
        if not heap:
            continue
        start, name, _ = heap[0]
        starts[job.key] = start
        cell = cells[name]
        free_at[name] = start + occupancy(job, cell)
        version[name] += 1
        for key in _pools(cell):
            heapq.heappush(heaps[key], (free_at[name], name, version[name]))
    return starts


def _pools(cell: Cell) -> tuple[_PoolKey, _PoolKey]:
    return cell.embodiment, (cell.embodiment, cell.task)
