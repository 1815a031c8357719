"""Dispatch benchmark (issue 9): what the node agent adds, as ratios to a same-run baseline.

Part 1, submit -> running / submit -> result (p50/p99 of a trivial job on a
warm image, next to ``armnet run --image`` in the same run; target: submit ->
running p50 < 2 s): see ``SUBMIT_TO_RUNNING`` below, left for the agent's
half of the issue.

Part 2, log throughput (``--logs``, the default): a real container (the test
bed's base image, real Podman through the Docker API) prints ``--lines`` lines;
the agent's own path follows it (``ContainerJob``'s log follow, then the
supervisor's line splitting and classification), and in the ``nats`` mode every
line goes through ``JobStream.line`` -> ``NatsLink`` -> JetStream, while a
subscriber in another process (a JetStream ordered consumer from the first
message, as a client following a job would use) counts the distinct lines it
receives. The ``follow`` mode is the same run without NATS: the baseline.
Printed per mode: lines/s (first -> last line seen by the reader),
lines lost, the ratio to the baseline, next to the target (>= 20,000 lines/s,
zero loss).

    PYTHONPATH=. ~/.cache/armnet/venv/bin/python bench/dispatch.py [--lines 100000] [--rounds 2]

Services: ``--nats-url`` and ``DOCKER_HOST`` when given, else the test bed's
nats-server and Podman API service are started for the run. Figures need a
quiet machine; on a loaded one the run only shows that the path works.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

TARGET_LINES_PER_S = 20_000
IDLE_S = 15.0
"""A reader that saw no new line for this long has seen all it will."""
LINE_PAD = "x" * 40
PRINTER = (
    "import sys\n"
    "w = sys.stdout.write\n"
    "for i in range({lines}):\n"
    "    w(f'bench line {{i:07d}} {pad}\\n')\n"
    "sys.stdout.flush()\n"
)


# ---------------------------------------------------------------- part 1 (agent)

SUBMIT_TO_RUNNING = None
"""Submit -> running and submit -> result (issue 9, Benchmark, first item): to be added by the
agent's half (kubectl apply a trivial RobotJob against the test bed's apiserver, operator and
agent; the same job through ``armnet run --image`` as the baseline). Nothing here measures it yet."""


# ---------------------------------------------------------------- part 2 (logs)


def subscriber(url: str, subject: str, expected: int, idle_s: float) -> None:
    """Child mode: count the distinct lines on ``subject`` from the first; print one JSON line."""
    import nats
    from nats.js.api import ConsumerConfig, DeliverPolicy

    async def run() -> dict[str, Any]:
        seen: set[str] = set()
        counts = {"messages": 0, "first_at": 0.0, "last_at": 0.0}
        complete = asyncio.Event()
        activity = asyncio.Event()

        async def on_message(msg: Any) -> None:  # a callback: next_msg() costs several times more
            counts["messages"] += 1
            activity.set()
            msg_id = (msg.headers or {}).get("Nats-Msg-Id", "")
            if msg_id not in seen:
                seen.add(msg_id)
                counts["last_at"] = time.time()
                counts["first_at"] = counts["first_at"] or counts["last_at"]
                if len(seen) >= expected:
                    complete.set()

        nc = await nats.connect(url)
        await nc.jetstream().subscribe(subject, ordered_consumer=True, cb=on_message,
                                       config=ConsumerConfig(deliver_policy=DeliverPolicy.ALL))
        print("ready", flush=True)
        while not complete.is_set():
            activity.clear()
            try:
                await asyncio.wait_for(activity.wait(), timeout=idle_s)
            except TimeoutError:
                break
        await nc.close()
        return {"distinct": len(seen), **counts}

    print(json.dumps(asyncio.run(run())), flush=True)


def start_container(client: Any, image: str, lines: int) -> Any:
    """The printing container on the agent's follow path (``ContainerJob``)."""
    try:
        from armnet_agent.launch.container import ULIMITS, ContainerJob
    except ImportError:  # before the launch/ refactor
        from armnet_agent.local_run.container import ULIMITS, ContainerJob
    from docker.types import Ulimit

    container = client.containers.create(
        image, command=["python3", "-c", PRINTER.format(lines=lines, pad=LINE_PAD)],
        network_mode="host", ulimits=[Ulimit(name=n, soft=s, hard=h) for n, s, h in ULIMITS],
        labels={"armnet.io/bench": "dispatch"}, detach=True,
    )
    container.start()
    return ContainerJob(client, container)


def follow(job: Any, on_line: Any) -> None:
    """The agent's reading of a job's output: the supervisor, its line splitting and classification."""
    from armnet_agent.supervise import JobHooks, SupervisorLimits, supervise

    counters: dict[str, int] = {}

    def on_event(event: Any) -> None:
        stream = event.stream.value
        seq = counters.get(stream, 0)
        counters[stream] = seq + 1
        on_line(stream, seq, event.text)

    supervise(job, SupervisorLimits(timeout_seconds=600, grace_seconds=5), JobHooks(on_event=on_event))


def run_follow(client: Any, image: str, lines: int) -> dict[str, float]:
    seen = [0]
    first_at, last_at = [0.0], [0.0]

    def on_line(stream: str, seq: int, text: str) -> None:
        if stream == "stdout" and text.startswith("bench line "):
            seen[0] += 1
            last_at[0] = time.time()
            first_at[0] = first_at[0] or last_at[0]

    job = start_container(client, image, lines)
    try:
        follow(job, on_line)
        # The supervisor returns after a bounded drain; its readers go on with what the
        # follow still has (a loaded machine lags), as they would in the agent.
        while seen[0] < lines and time.time() - max(last_at[0], first_at[0]) < IDLE_S:
            time.sleep(0.05)
    finally:
        job.remove()
    return {"lines_per_s": rate(seen[0], first_at[0], last_at[0]), "lost": lines - seen[0]}


def rate(count: int, first_at: float, last_at: float) -> float:
    """Lines per second from the first line seen to the last (container start-up left out)."""
    return (count - 1) / (last_at - first_at) if count > 1 and last_at > first_at else 0.0


def run_nats(client: Any, image: str, lines: int, nats_url: str) -> dict[str, float]:
    from armnet_agent.node.streams import JobStream, NatsLink, StreamSettings

    namespace, uid = "bench", uuid.uuid4().hex
    link = NatsLink(StreamSettings(url=nats_url)).start()
    stream = JobStream(link, namespace, uid)
    child = subprocess.Popen(
        [sys.executable, __file__, "--subscribe", nats_url, stream.subject("stdout"), str(lines)],
        stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": REPO + os.pathsep
                                                + os.environ.get("PYTHONPATH", "")},
    )
    try:
        assert child.stdout is not None
        if child.stdout.readline().strip() != "ready":
            raise RuntimeError("the subscriber did not start")
        deadline = time.monotonic() + 30
        while not link.connected and time.monotonic() < deadline:
            time.sleep(0.05)

        def on_line(kind: str, seq: int, text: str) -> None:
            stream.line(kind, seq, text)

        job = start_container(client, image, lines)
        try:
            follow(job, on_line)
        finally:
            job.remove()
        report = json.loads(child.stdout.readline() or "{}")
        child.wait(30)
    finally:
        if child.poll() is None:
            child.kill()
        link.stop(timeout_s=10)
    distinct = int(report.get("distinct", 0))
    return {
        "lines_per_s": rate(distinct, float(report.get("first_at", 0.0)), float(report.get("last_at", 0.0))),
        "lost": lines - distinct,
        "dropped": link.dropped,
    }


@contextmanager
def services(args: argparse.Namespace) -> Iterator[tuple[Any, str, str]]:
    """(Docker client, base image, NATS URL): given ones, or the test bed's started for this run."""
    with ExitStack() as stack:
        nats_url = args.nats_url
        if nats_url is None:
            from tests.testbed.natsd import NatsServer

            nats_url = stack.enter_context(NatsServer()).url
        if os.environ.get("DOCKER_HOST"):
            import docker

            client = docker.DockerClient(base_url=os.environ["DOCKER_HOST"], timeout=None)
        else:
            from tests.testbed.podman import PodmanService

            service = PodmanService().start()
            stack.callback(service.stop)
            client = service.client
        from tests.testbed.images import BASE_IMAGE, require_base_image

        require_base_image(client)
        yield client, BASE_IMAGE, nats_url


def log_throughput(args: argparse.Namespace) -> None:
    results: dict[str, list[dict[str, float]]] = {"follow": [], "nats": []}
    with services(args) as (client, image, nats_url):
        for _ in range(args.rounds):  # the modes take turns, so both see the same machine load
            results["follow"].append(run_follow(client, image, args.lines))
            results["nats"].append(run_nats(client, image, args.lines, nats_url))

    baseline = statistics.median(r["lines_per_s"] for r in results["follow"])
    print(f"\nlog throughput: {args.lines} lines x {args.rounds} round(s), median per mode")
    print(f"{'mode':<8} {'lines/s':>10} {'lost':>6} {'vs follow':>10}   target")
    for mode, runs in results.items():
        rate = statistics.median(r["lines_per_s"] for r in runs)
        lost = max(int(r["lost"]) for r in runs)
        target = "(baseline)" if mode == "follow" else (
            f">= {TARGET_LINES_PER_S} lines/s, 0 lost: "
            + ("met" if rate >= TARGET_LINES_PER_S and lost == 0 else "NOT met"))
        print(f"{mode:<8} {rate:>10.0f} {lost:>6} {rate / baseline:>9.2f}x   {target}")
    dropped = max(int(r.get("dropped", 0)) for r in results["nats"])
    print(f"NatsLink dropped (max over rounds): {dropped}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--lines", type=int, default=100_000)
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--nats-url", default=None, help="an existing nats-server -js (default: start one)")
    parser.add_argument("--subscribe", nargs=3, metavar=("URL", "SUBJECT", "N"), help=argparse.SUPPRESS)
    parser.add_argument("--idle", type=float, default=IDLE_S, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscribe:
        url, subject, count = args.subscribe
        subscriber(url, subject, int(count), args.idle)
        return
    log_throughput(args)


if __name__ == "__main__":
    main()
