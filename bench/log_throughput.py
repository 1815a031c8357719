"""Log throughput to the customer's terminal: a burst of output lines, agent -> NATS -> ``armnet logs -f``.

The path measured is the real one end to end: the node agent's publisher
(``JobStream.line`` -> ``NatsLink``, its outbox joining the lines that wait
into messages of several lines, JetStream acks) in this process, fed from a
thread as the agent's supervisor feeds it; the test bed's nats-server; and the
real ``armnet logs -f <job>`` in its own process (the RobotJob read from the
test bed's kube-apiserver, heartbeats on), rendering into a pipe. A reader
process at the other end of the pipe audits every printed line against what
the job printed: each line once, whole, in order, with its own timestamp (the
runtime's prefix, printed to the millisecond).

The baseline, in the same run and alternated with it: a plain nats-py
subscriber (a JetStream ordered push consumer with a callback, the fastest
reader docs/streams.md shows) in its own process on the same subjects, auditing
the same lines (``armnet_core.logbatch`` to split the messages). Rates are
lines per second from the moment the burst was handed to the agent to the last
line the reader saw; the ratio is ``armnet logs -f`` to the plain subscriber.
Next to them, CPU time per line (from /proc, so the machine's load barely moves
it): the agent's process during the burst, and the reader's (the ``armnet``
process, or the plain subscriber's).
``--unbatched`` adds the same ``armnet logs -f`` run with an agent sending one
line per message (``batch_max_lines=1``: the single-line format, which the client still reads).

    PYTHONPATH=. ~/.cache/armnet/venv/bin/python bench/log_throughput.py [--lines 20000 200000] [--rounds 3]

Target: >= 50,000 lines/s to ``armnet logs -f``, none lost, in order. The
2-core VM is shared: figures vary with its load; compare the modes within one
run, and measure on a quiet machine for absolute figures.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from datetime import UTC, datetime, timedelta
from typing import Any

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

TARGET_LINES_PER_S = 50_000
IDLE_S = 60.0
"""A reader that saw nothing new for this long has seen all it will."""
PAD = "x" * 40
BASE_TIME = datetime(2026, 11, 28, 12, 0, 0, tzinfo=UTC)
CHILD_ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(
    [os.path.join(REPO, p) for p in ("runtime/src", "operator", "agent", "cli", "fms")] + [REPO]
    + [os.environ.get("PYTHONPATH", "")])}


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used so far: a figure the machine's load barely moves."""
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def printed_lines(count: int) -> list[str]:
    """What the job prints: numbered lines with the runtime's timestamp prefix, one microsecond apart."""
    from armnet_runtime.markers import format_timestamp

    return [f"{format_timestamp(BASE_TIME + timedelta(microseconds=i))} bench line {i:07d} {PAD}"
            for i in range(count)]


class Audit:
    """What a reader got of the burst: each expected line once, whole, in order, or not."""

    def __init__(self, expected: dict[bytes, int]) -> None:
        self.expected = expected
        self.seen = bytearray(len(expected))
        self.whole = self.others = self.duplicates = self.late = 0
        self.highest = -1
        self.last_at = 0.0

    def feed(self, line: bytes) -> None:
        index = self.expected.get(line)
        if index is None:
            self.others += 1  # a status line, or a cut/garbled one (then "lost" shows it)
            return
        if self.seen[index]:
            self.duplicates += 1
            return
        self.seen[index] = 1
        self.whole += 1
        if index < self.highest:
            self.late += 1
        self.highest = max(self.highest, index)
        self.last_at = time.time()

    def report(self) -> dict[str, float]:
        return {"whole": self.whole, "lost": len(self.expected) - self.whole, "duplicates": self.duplicates,
                "late": self.late, "last_at": self.last_at, "others": self.others}


# ---------------------------------------------------------------- readers (child processes)


def read_plain(url: str, namespace: str, job_id: str, count: int) -> None:
    """Child: a plain nats-py subscriber on the job's subjects; prints "ready", then its audit as JSON."""
    import nats
    from armnet_core.logbatch import split_lines
    from nats.js.api import ConsumerConfig, DeliverPolicy

    audit = Audit({line.encode(): i for i, line in enumerate(printed_lines(count))})
    status_suffix = ".status"

    async def run() -> dict[str, float]:
        ready, done, activity = asyncio.Event(), asyncio.Event(), asyncio.Event()

        async def on_message(msg: Any) -> None:
            activity.set()
            if msg.subject.endswith(status_suffix):
                phase = json.loads(msg.data).get("phase")
                (ready if phase == "running" else done).set()
                return
            for _, line in split_lines(msg.data, msg.headers):
                audit.feed(line)

        nc = await nats.connect(url)
        await nc.jetstream().subscribe(f"logs.{namespace}.{job_id}.>", ordered_consumer=True, cb=on_message,
                                       config=ConsumerConfig(deliver_policy=DeliverPolicy.ALL))
        await asyncio.wait_for(ready.wait(), timeout=IDLE_S)
        cpu_at_ready = cpu_s(os.getpid())
        print("ready", flush=True)
        while not done.is_set():
            activity.clear()
            try:
                await asyncio.wait_for(activity.wait(), timeout=IDLE_S)
            except TimeoutError:
                break
        cpu = cpu_s(os.getpid()) - cpu_at_ready
        await nc.close()
        return {**audit.report(), "reader_cpu_s": cpu}

    print(json.dumps(asyncio.run(run())), flush=True)


def read_cli(url: str, namespace: str, name: str, kubeconfig: str, count: int) -> None:
    """Child: ``armnet logs -f`` into a pipe, read here; prints "ready", then its audit as JSON."""
    expected = {f"{line[:23]}Z {line[28:]}".encode(): i for i, line in enumerate(printed_lines(count))}
    audit = Audit(expected)
    cli = subprocess.Popen(
        [sys.executable, "-c", "import sys; from armnet_cli.main import main; sys.exit(main())",
         "logs", "-f", name, "-n", namespace, "--kubeconfig", kubeconfig, "--nats-url", url],
        stdout=subprocess.PIPE, env=CHILD_ENV,
    )
    assert cli.stdout is not None
    ready = False
    cpu_at_ready = 0.0
    cpu_at_end = 0.0
    rest = b""
    while True:
        chunk = os.read(cli.stdout.fileno(), 1 << 16)
        if not chunk:
            break
        lines = (rest + chunk).split(b"\n")
        rest = lines.pop()
        for line in lines:
            if not ready and line.endswith(b"[status: running]"):
                ready = True
                cpu_at_ready = cpu_s(cli.pid)
                print("ready", flush=True)
                continue
            if line.endswith(b"[status: succeeded]"):
                cpu_at_end = cpu_s(cli.pid)  # before the process exits (its exit frees, and costs, more)
            audit.feed(line)
    code = cli.wait()
    print(json.dumps({**audit.report(), "exit_code": code, "reader_cpu_s": cpu_at_end - cpu_at_ready}),
          flush=True)


# ---------------------------------------------------------------- one burst


def burst(link: Any, reader: list[str], namespace: str, job_id: str, lines: list[str]) -> dict[str, float]:
    """Publish "running", start ``reader``, then the burst and the terminal status; the reader's figures."""
    from armnet_node.streams import JobStream

    stream = JobStream(link, namespace, job_id)
    stream.status("running", {})
    child = subprocess.Popen([sys.executable, __file__, *reader], stdout=subprocess.PIPE, text=True,
                             env=CHILD_ENV)
    try:
        assert child.stdout is not None
        if child.stdout.readline().strip() != "ready":
            raise RuntimeError(f"the reader {reader[0]} did not start")

        def job_output() -> None:
            for seq, text in enumerate(lines, start=1):
                stream.line("stdout", seq, text)
            stream.status("succeeded", {"exitCode": 0})

        published_before = link.published
        agent_cpu_before = cpu_s(os.getpid())
        started = time.time()
        writer = threading.Thread(target=job_output, name="bench-job-output")
        writer.start()
        writer.join()
        while link.published - published_before < len(lines) + 1 and time.time() - started < IDLE_S:
            time.sleep(0.001)
        acked_at = time.time()
        agent_cpu = cpu_s(os.getpid()) - agent_cpu_before
        report = json.loads(child.stdout.readline() or "{}")
        child.wait(30)
    finally:
        if child.poll() is None:
            child.kill()
    whole = int(report.get("whole", 0))
    last_at = float(report.get("last_at", 0.0))
    return {
        "lines_per_s": whole / (last_at - started) if whole and last_at > started else 0.0,
        "agent_lines_per_s": len(lines) / (acked_at - started),
        "agent_cpu_us": agent_cpu / len(lines) * 1e6,
        "reader_cpu_us": float(report.get("reader_cpu_s", 0.0)) / len(lines) * 1e6,
        "lost": float(report.get("lost", len(lines))), "duplicates": float(report.get("duplicates", 0)),
        "late": float(report.get("late", 0)), "exit_code": float(report.get("exit_code", 0)),
    }


@contextmanager
def services(args: argparse.Namespace) -> Iterator[tuple[str, Any]]:
    """(NATS URL, control plane): the given NATS or the test bed's, and the test bed's kube-apiserver."""
    with ExitStack() as stack:
        nats_url = args.nats_url
        if nats_url is None:
            from armnet_testbed.natsd import NatsServer

            nats_url = stack.enter_context(NatsServer()).url
        from armnet_testbed.kube import ControlPlane

        yield nats_url, stack.enter_context(ControlPlane())


def cli_job(plane: Any, namespace: str, name: str) -> str:
    """A RobotJob for ``armnet logs`` to find; its UID (the agent publishes under it)."""
    from armnet_client import Client
    from armnet_core.models import JobSpec

    client = Client(kubeconfig=str(plane.kubeconfig), namespace=namespace, env={})
    client.submit(JobSpec(image="localhost/bench:dev", embodiment="bench/logs"), name=name)
    uid = client.read(name).metadata.uid
    assert uid
    return uid


def run(args: argparse.Namespace) -> None:
    from armnet_node.streams import NatsLink, StreamSettings

    modes = ["plain", "armnet logs -f"] + (["armnet logs -f, unbatched"] if args.unbatched else [])
    with services(args) as (nats_url, plane):
        links = {"batched": NatsLink(StreamSettings(url=nats_url)).start(),
                 "unbatched": NatsLink(StreamSettings(url=nats_url, batch_max_lines=1)).start()}
        deadline = time.monotonic() + 30
        while not all(link.connected for link in links.values()) and time.monotonic() < deadline:
            time.sleep(0.05)
        namespace = plane.create_namespace("logbench")
        try:
            for count in args.lines:
                lines = printed_lines(count)
                results: dict[str, list[dict[str, float]]] = {mode: [] for mode in modes}
                for round_index in range(args.rounds):  # the modes take turns: all see the same load
                    for mode in modes:
                        name = f"burst-{count}-{round_index}-{len(results[mode])}-{modes.index(mode)}"
                        job_id = cli_job(plane, namespace, name)
                        if mode == "plain":
                            reader = ["--read-plain", nats_url, namespace, job_id, str(count)]
                        else:
                            reader = ["--read-cli", nats_url, namespace, name, str(plane.kubeconfig), str(count)]
                        link = links["unbatched" if mode.endswith("unbatched") else "batched"]
                        results[mode].append(burst(link, reader, namespace, job_id, lines))
                print_table(count, args.rounds, results)
            print(f"agent link dropped: {sum(link.dropped for link in links.values())}")
        finally:
            for link in links.values():
                link.stop(timeout_s=10)


def print_table(count: int, rounds: int, results: dict[str, list[dict[str, float]]]) -> None:
    baseline = statistics.median(r["lines_per_s"] for r in results["plain"])
    print(f"\n{count} lines x {rounds} round(s), median per mode; lost/dups/late: the worst round")
    print(f"{'reader':<28} {'lines/s':>9} {'vs plain':>9} {'agent acked/s':>14} {'CPU us/line: agent':>19} "
          f"{'reader':>7} {'lost':>5} {'dups':>5} {'late':>5}   target")
    for mode, runs in results.items():
        rate = statistics.median(r["lines_per_s"] for r in runs)
        agent = statistics.median(r["agent_lines_per_s"] for r in runs)
        agent_cpu = statistics.median(r["agent_cpu_us"] for r in runs)
        reader_cpu = statistics.median(r["reader_cpu_us"] for r in runs)
        worst = {k: max(int(r[k]) for r in runs) for k in ("lost", "duplicates", "late", "exit_code")}
        complete = worst["lost"] == worst["duplicates"] == worst["late"] == worst["exit_code"] == 0
        if mode == "plain":
            target = "(baseline)"
        else:
            met = rate >= TARGET_LINES_PER_S and complete
            target = f">= {TARGET_LINES_PER_S} lines/s, none lost, in order: " + ("met" if met else "NOT met")
        print(f"{mode:<28} {rate:>9.0f} {rate / baseline if baseline else 0:>8.2f}x {agent:>14.0f} "
              f"{agent_cpu:>19.1f} {reader_cpu:>7.1f} {worst['lost']:>5} {worst['duplicates']:>5} "
              f"{worst['late']:>5}   {target}")
        assert complete, f"{mode}: lines lost, repeated or out of order ({worst})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--lines", type=int, nargs="+", default=[20_000, 200_000])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--unbatched", action="store_true",
                        help="also run armnet logs -f with an agent sending one line per message")
    parser.add_argument("--nats-url", default=None, help="an existing nats-server -js (default: start one)")
    parser.add_argument("--read-plain", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--read-cli", nargs=5, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.read_plain:
        url, namespace, job_id, count = args.read_plain
        read_plain(url, namespace, job_id, int(count))
    elif args.read_cli:
        url, namespace, name, kubeconfig, count = args.read_cli
        read_cli(url, namespace, name, kubeconfig, int(count))
    else:
        run(args)


if __name__ == "__main__":
    main()
