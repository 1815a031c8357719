"""When a waiting RobotJob will start: at the latest, and likely. Pure.

The latest start is the bound a batch scheduler gives from time limits (Slurm's
expected start): every running job and every job ahead in the queue is assumed to use
its whole ``timeoutSeconds`` plus its cell's grace period, and each waiting job, in
queue order, takes the matching cell that frees first. A job that ends early only
makes the start earlier, so the time is a promise the queue can keep, not a guess.

The likely start is the same walk with each job ahead taking its embodiment's typical
run instead (the median of its ``RECENT_RUNS`` latest finished runs, read from the
finished RobotJobs still in the cluster, so it survives an operator restart), never
more than its timeout and grace: a job that has already run longer than typical is
counted as ending now. With no finished run of the embodiment yet, the likely start
is the latest one.

Only jobs that wait for busy cells get one: a job waiting for its quota, for a cell
that is offline, faulted or cordoned, or for a cell that does not exist has no
bound in time (it waits on a person).

Cost: one heap per cell pool (embodiment, and embodiment with task), so each waiting
job costs O(log cells) amortised, like the scheduling pass it follows.
"""

from __future__ import annotations

import heapq
import statistics
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime, timedelta

from .duty_cycle import NO_STATE, DutyState, ready_at
from .model import Cell, CellQueue, Job

_PoolKey = tuple[str, str | None] | str
#: How long a job holds a cell, by the job and the cell.
Occupancy = Callable[[Job, Cell], timedelta]
#: How many of an embodiment's latest finished runs its typical run is the median of.
RECENT_RUNS = 20


@dataclass(frozen=True)
class Seat:
    """A cell that can run the queue's jobs, when it can start the next at the latest, and its duty
    cycle's state from then on (``duty_cycle.ready_at``: a rest due is taken before that start)."""

    cell: Cell
    free_at: datetime
    duty: DutyState = NO_STATE


def seats(cells: Iterable[Cell], holders: Mapping[str, Job], now: datetime,
          occupancy: Occupancy | None = None) -> list[Seat]:
    """Each available cell with the moment its job (``holders``, by cell name) leaves it.

    A job that has started leaves at its start plus its ``occupancy`` (by default the
    longest: timeout plus grace); one bound but not started yet at its binding plus the
    same (it starts at once on a ready cell). A job past that moment is counted as
    leaving now. A cell with a duty cycle rests first when its rest is due by then.
    """
    occupancy = occupancy or longest_occupancy
    result = []
    for cell in cells:
        job = holders.get(cell.name)
        free_at = now
        if job is not None:
            since = job.started_at or job.bound_at or now
            free_at = max(now, since + occupancy(job, cell))
        ready, duty = ready_at(cell.duty_cycle, cell.duty, free_at, now)
        result.append(Seat(cell, ready, duty))
    return result


def longest_occupancy(job: Job, cell: Cell) -> timedelta:
    """The longest a job holds a cell: its timeout, then the cell's grace period."""
    return timedelta(seconds=job.timeout_seconds) + cell.grace_period


def typical_runs(jobs: Iterable[Job], recent: int = RECENT_RUNS) -> dict[str, timedelta]:
    """Embodiment -> the median of its ``recent`` latest finished runs (started to finished)."""
    runs: dict[str, list[tuple[datetime, timedelta]]] = defaultdict(list)
    for job in jobs:
        if job.terminal and job.started_at is not None and job.finished_at is not None \
                and job.finished_at >= job.started_at:
            runs[job.embodiment].append((job.finished_at, job.finished_at - job.started_at))
    typical = {}
    for embodiment, finished in runs.items():
        latest = heapq.nlargest(recent, finished, key=lambda run: run[0])
        typical[embodiment] = statistics.median_low(duration for _, duration in latest)
    return typical


def likely_occupancy(typical: Mapping[str, timedelta]) -> Occupancy:
    """A job's embodiment's typical run, never more than the longest it may hold the cell."""
    def occupancy(job: Job, cell: Cell) -> timedelta:
        longest = longest_occupancy(job, cell)
        return min(longest, typical.get(job.embodiment, longest))

    return occupancy


def queue_starts(queue: Iterable[Job], available: Iterable[Seat],
                  occupancy: Occupancy | None = None) -> dict[str, datetime]:
    """Job key -> the moment it starts, for ``queue`` in its order (the first starts first).

    Each job takes the matching seat that frees first and holds it for its ``occupancy``
    (by default the longest, which makes the moments the latest starts), and a cell with a
    duty cycle rests after it when its working time is up by then. A job with a
    task draws from the cells of its (embodiment, task); one without, from every cell
    of its embodiment. A job no seat matches gets no entry.
    """
    occupancy = occupancy or longest_occupancy
    free_at: dict[str, datetime] = {}
    duty: dict[str, DutyState] = {}
    version: dict[str, int] = defaultdict(int)
    cells: dict[str, Cell] = {}
    heaps: dict[_PoolKey, list[tuple[datetime, str, int]]] = defaultdict(list)
    for seat in available:
        name = seat.cell.name
        cells[name], free_at[name], duty[name] = seat.cell, seat.free_at, seat.duty
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
        free_at[name], duty[name] = ready_at(cell.duty_cycle, duty[name], start + occupancy(job, cell), start)
        version[name] += 1
        for key in _pools(cell):
            heapq.heappush(heaps[key], (free_at[name], name, version[name]))
    return starts


def cell_queues(cells: Iterable[Cell], waiting: Iterable[Job], holders: Mapping[str, Job], now: datetime,
                typical: Mapping[str, timedelta]) -> dict[str, CellQueue]:
    """Cell name -> the jobs waiting for a cell like it, and when its job likely ends and ends at the latest.

    For the cell operator, who plans resets and breaks around the queue: a job
    waits for this cell when it could run here (its embodiment, and its task if it
    names one), whatever it waits on. A cell nobody holds has no free time (it is free).
    """
    demand: dict[_PoolKey, int] = defaultdict(int)
    for job in waiting:
        demand[job.embodiment if job.task is None else (job.embodiment, job.task)] += 1
    likely = likely_occupancy(typical)
    summary = {}
    for cell in cells:
        count = sum(demand.get(key, 0) for key in _pools(cell))
        holder = holders.get(cell.name)
        if holder is None:
            summary[cell.name] = CellQueue(count)
            continue
        since = holder.started_at or holder.bound_at or now
        summary[cell.name] = CellQueue(count, max(now, since + likely(holder, cell)),
                                       max(now, since + longest_occupancy(holder, cell)))
    return summary


def _pools(cell: Cell) -> tuple[_PoolKey, _PoolKey]:
    return cell.embodiment, (cell.embodiment, cell.task)
