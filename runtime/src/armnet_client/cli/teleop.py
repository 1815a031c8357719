"""``armnet teleop JOB --leader PORT|sim``: drive a running job's follower arm from a leader arm.

Samples the leader at ``--rate`` and publishes the latest action; on a terminal,
Right arrow / Left arrow / Esc send ``next_episode`` / ``rerecord_episode`` /
``stop_recording`` (Esc also ends the session). Ctrl-C ends it too. On a terminal
two live lines show what was sent and the follower's state as the job reports it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import shutil
import sys
import time
from collections.abc import Iterator
from typing import Optional

from ..errors import NatsUnreachable
from ..teleop import (
    FollowerView,
    events_of_keys,
    leader_label,
    redraw,
    simulated_action,
    status_lines,
)
from ..teleop_link import Leader, TeleopStats, lerobot_leader, run_session
from .common import add_cluster_options, client_from, guarded

EXAMPLES = """
  armnet teleop pick-7x2k --leader sim                  # a simulated leader (slow sines)
  armnet teleop pick-7x2k --leader /dev/ttyACM1 --leader-id my_leader --rate 30
keys: Right arrow next_episode, Left arrow rerecord_episode, Esc stop_recording (and quit).
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", help="the RobotJob name (it must be running)")
    parser.add_argument("--leader", required=True, help="the leader arm's serial port, or sim")
    parser.add_argument("--leader-id", help="the leader's LeRobot calibration id")
    parser.add_argument("--rate", type=float, default=30.0, help="actions per second (30)")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    add_cluster_options(parser, EXAMPLES)


@contextlib.contextmanager
def raw_terminal(fd: int) -> Iterator[bool]:
    """Put a terminal in cbreak mode for single keys; ``False`` (no keys) when ``fd`` is no terminal."""
    if not os.isatty(fd):
        yield False
        return
    import termios
    import tty

    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield True
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


async def _session(url: str, ns: str, job_id: str, args: argparse.Namespace) -> TeleopStats:
    loop = asyncio.get_running_loop()
    events: asyncio.Queue[str] = asyncio.Queue()
    disconnect = None
    leader: Leader
    if args.leader == "sim":
        leader = simulated_action
    else:
        leader, disconnect = lerobot_leader(args.leader, args.leader_id)
    fd = sys.stdin.fileno()
    drawn = 0

    def on_tick(stats: TeleopStats) -> None:
        nonlocal drawn
        if not sys.stderr.isatty():
            return
        follower = FollowerView() if stats.follower_at is None else FollowerView(
            stats.follower, time.monotonic() - stats.follower_at)
        lines = status_lines(args.leader, stats.actions, stats.last_event, follower)
        sys.stderr.write(redraw(lines, drawn, shutil.get_terminal_size().columns))
        sys.stderr.flush()
        drawn = len(lines)

    def read_keys() -> None:
        for event in events_of_keys(os.read(fd, 64)):
            events.put_nowait(event)

    with raw_terminal(fd) as keys:
        if keys:
            loop.add_reader(fd, read_keys)
        try:
            return await run_session(url, ns, job_id, leader, rate_hz=args.rate, events=events,
                                     duration_s=args.duration, on_tick=on_tick)
        finally:
            if keys:
                loop.remove_reader(fd)
            if disconnect is not None:
                disconnect()


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        client = client_from(args)
        job = client.read(args.job)
        url: Optional[str] = client.nats_url
        if not url:
            raise NatsUnreachable("teleop needs NATS: pass --nats-url or set ARMNET_NATS_URL")
        ns = job.metadata.namespace or client.namespace
        job_id = job.status.job_id or job.metadata.uid or ""
        print(f"teleoperating robotjob/{args.job} with the {leader_label(args.leader)} at "
              f"{args.rate:g}/s; Right: next episode, Left: re-record, Esc: stop", file=sys.stderr)
        stats = asyncio.run(_session(url, ns, job_id, args))
        print(f"\nsent {stats.actions} actions and {stats.events} events", file=sys.stderr)
        return 0

    return guarded(body)
