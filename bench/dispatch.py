"""Dispatch benchmark: what the node agent adds, as ratios to a same-run baseline.

Part 1, dispatch (``--dispatch``): submit -> running and submit -> result of
a trivial job on a warm image, p50/p99 over ``--rounds``. The platform: the test
bed's kube-apiserver with ``armnet operator`` and ``armnet agent`` as processes
(``e2e/agent_bed.py``, one simulated cell, NATS on), the RobotJob created
through the API; "running" and "result" are when a watch from this process
sees the phase ``running`` and a terminal phase. Twice: with the container-engine
launcher (Podman) and, on the test bed's real node (containerd + kubelet, its
host-wide lock), with the pod launcher (``--launcher pod``: the job's pod with
the connector as its native sidecar, the cell's devices through the agent's
device plugin; "running" is when the job's container has started). The
baseline, in the same run and alternated with both: the same script the way ``armnet run --image``
runs it (a ``LocalCell``, ``ContainerJob.start``, the supervisor); "running"
is when the container was started, "result" when the supervisor returns.
Printed: all three, and each platform path's ratio to the baseline, next to the
target (submit -> running p50 < 2 s, each launcher). One untimed round of each
warms the images. ``--no-node``: the container-engine launcher only.

Part 2, log throughput (``--logs``, the default): a real container (the test
bed's base image, real Podman through the Docker API) prints ``--lines`` lines;
the agent's own path follows it (``ContainerJob``'s log follow, then the
supervisor's line splitting and classification), and in the ``nats`` mode every
line goes through ``JobStream.line`` -> ``NatsLink`` -> JetStream, while a
subscriber in another process (a JetStream ordered consumer from the first
message, as a client following a job would use) audits what it receives (one
message per id, one line or a batch of them): every printed line whole, once, in order, or lost, cut into
fragments, repeated or late. The ``follow`` mode is the same run without NATS: the baseline
(``ContainerJob`` reading Podman's k8s-file log file); the ``api`` mode is that
path with the Docker API's follow instead (the fallback, and the path before).
Printed per mode: lines/s (first -> last line seen by the reader),
lines lost, the ratio to the baseline, next to the target (>= 20,000 lines/s,
zero loss).

    PYTHONPATH=. ~/.cache/armnet/venv/bin/python bench/dispatch.py [--lines 100000] [--rounds 2]
    PYTHONPATH=. ~/.cache/armnet/venv/bin/python bench/dispatch.py --dispatch [--rounds 10] [--no-node]

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
import threading
import time
import uuid
from abc import ABC, abstractmethod
from collections.abc import Collection, Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

TARGET_LINES_PER_S = 20_000
IDLE_S = 60.0
"""A reader that saw no new line for this long has seen all it will (a re-read finished log comes late)."""
LINE_PAD = "x" * 40
PRINTER = (
    "import sys\n"
    "w = sys.stdout.write\n"
    "for i in range({lines}):\n"
    "    w(f'bench line {{i:07d}} {pad}\\n')\n"
    "sys.stdout.flush()\n"
)



class LineAudit:
    """What a reader got of the printer's lines: each whole line once, in order, or not.

    A line is whole when it is exactly what the printer wrote; anything else is a
    fragment (an engine that cuts a line). ``late`` counts whole lines that came after
    a later one (delivered out of order, e.g. recovered from the finished log).
    """

    def __init__(self) -> None:
        self.indices: set[int] = set()
        self.fragments = self.duplicates = self.late = 0
        self._highest = -1

    def feed(self, text: str) -> bool:
        """True for a whole line."""
        head, _, pad = text.partition(" " + LINE_PAD[:1])
        number = head.removeprefix("bench line ")
        if not (head.startswith("bench line ") and len(number) == 7 and number.isdigit()
                and text == f"{head} {LINE_PAD}"):
            self.fragments += 1
            return False
        index = int(number)
        if index in self.indices:
            self.duplicates += 1
        self.indices.add(index)
        if index < self._highest:
            self.late += 1
        self._highest = max(self._highest, index)
        return True

    def report(self, expected: int) -> dict[str, float]:
        return {"lost": expected - len(self.indices), "fragments": self.fragments,
                "duplicates": self.duplicates, "late": self.late}


# ---------------------------------------------------------------- part 1 (dispatch)

TRIVIAL = """
from armnet_runtime import Context, main


@main
def run(ctx: Context):
    print("hello from the job", flush=True)
    return {"ok": True}
"""
TARGET_RUNNING_P50_S = 2.0
CONTAINER_PATH = "kubectl apply (agent)"
POD_PATH = "kubectl apply (agent, pod)"


class _FirstSeen(ABC):
    """When this process first saw each (job name, stage) pair in a namespace, from a watch it keeps open.

    A subclass says what it watches (``_events``) and which stages one object shows (``_stages``).
    """

    thread_name = "bench-watch"

    def __init__(self, api_client: Any, namespace: str) -> None:
        self._api_client = api_client
        self.namespace = namespace
        self.seen: dict[tuple[str, str], float] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        threading.Thread(target=self._run, name=self.thread_name, daemon=True).start()

    @abstractmethod
    def _events(self) -> Iterator[Any]:
        """The watch's events (it ends when the server ends the watch; ``_run`` opens another)."""

    @abstractmethod
    def _stages(self, obj: Any) -> tuple[str, list[str]]:
        """The job's name and the stages this object shows it has reached."""

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                for event in self._events():
                    now = time.monotonic()
                    name, stages = self._stages(event["object"])
                    with self._lock:
                        for stage in stages:
                            self.seen.setdefault((name, stage), now)
                    if self._stop.is_set():
                        return
            except Exception:  # noqa: BLE001 - a dropped watch is re-opened; the bench only reads times
                time.sleep(0.2)

    def stop(self) -> None:
        self._stop.set()


class PhaseWatch(_FirstSeen):
    """When this process first saw each RobotJob of a namespace in each phase (a watch, as a client)."""

    def _events(self) -> Iterator[Any]:
        from armnet_core.api import GROUP, ROBOTJOBS, VERSION
        from kubernetes import client, watch

        api = client.CustomObjectsApi(self._api_client)
        return watch.Watch().stream(api.list_namespaced_custom_object, GROUP, VERSION,
                                    self.namespace, ROBOTJOBS, timeout_seconds=30)

    def _stages(self, obj: Any) -> tuple[str, list[str]]:
        phase = (obj.get("status") or {}).get("phase")
        return obj["metadata"]["name"], [phase] if phase else []

    def wait(self, name: str, phases: Collection[str], timeout: float) -> tuple[str, float]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self._lock:
                hits = [(at, phase) for (n, phase), at in self.seen.items() if n == name and phase in phases]
            if hits:
                at, phase = min(hits)
                return phase, at
            time.sleep(0.01)
        raise TimeoutError(f"job {name} did not reach {phases} in {timeout} s")


class PodStages(_FirstSeen):
    """When this process first saw each job pod of a namespace reach each start-up stage (a pod watch).

    Where the pod launcher's submit -> running goes: the pod created by the agent, the
    connector sidecar's container running, its startup probe passed (it serves), the job's
    container running; keyed by the job's name (the pod's ``armnet.io/job`` annotation).
    """

    STAGES = ("pod created", "connector running", "connector serves", "job container running")
    thread_name = "bench-pod-watch"

    def _events(self) -> Iterator[Any]:
        from kubernetes import client, watch

        core = client.CoreV1Api(self._api_client)
        return watch.Watch().stream(core.list_namespaced_pod, self.namespace, timeout_seconds=30)

    def _stages(self, pod: Any) -> tuple[str, list[str]]:
        from armnet_core.api import JOB_ANNOTATION

        job = (pod.metadata.annotations or {}).get(JOB_ANNOTATION, "").rpartition("/")[2]
        reached = ["pod created"]
        status = pod.status
        for entry in (status.init_container_statuses if status else None) or []:
            if entry.name == "connector" and entry.state and entry.state.running:
                reached.append("connector running")
                if entry.started:
                    reached.append("connector serves")
        for entry in (status.container_statuses if status else None) or []:
            if entry.name == "job" and entry.state and (entry.state.running or entry.state.terminated):
                reached.append("job container running")
        return job, reached

    def of(self, name: str, submitted: float) -> dict[str, float]:
        with self._lock:
            return {stage: self.seen[(name, stage)] - submitted for stage in self.STAGES if (name, stage) in self.seen}


def platform_round(bed: Any, api: Any, watch: PhaseWatch, image: str, round_name: str,
                   pods: PodStages | None = None) -> dict[str, float]:
    """One trivial RobotJob through the apiserver, the operator and the agent."""
    from armnet_core.api import API_VERSION, GROUP, ROBOTJOBS, TERMINAL_PHASES, VERSION

    name = f"dispatch-{round_name}"
    body = {"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": name},
            "spec": {"image": image, "embodiment": "lerobot/so-101", "task": bed.node, "timeoutSeconds": 120}}
    submitted = time.monotonic()
    api.create_namespaced_custom_object(GROUP, VERSION, bed.namespace, ROBOTJOBS, body)
    _, running = watch.wait(name, {"running", *TERMINAL_PHASES}, 120)
    phase, done = watch.wait(name, TERMINAL_PHASES, 120)
    if phase != "succeeded":
        raise RuntimeError(f"the bench job {name} ended {phase}: {bed.job(name).get('status')}")
    stages = {f"stage:{k}": v for k, v in pods.of(name, submitted).items()} if pods is not None else {}
    return {"running_s": running - submitted, "result_s": done - submitted, **stages}


def local_round(client: Any, image: str, script: Any) -> dict[str, float]:
    """The same script as ``armnet run --image`` runs it: a local cell, the job container, the supervisor."""
    import tempfile
    from pathlib import Path

    from armnet_launch.cell_spec import build_job_env, resolve_spec
    from armnet_launch.container import ContainerJob
    from armnet_launch.sim_cell import LocalCell
    from armnet_launch.supervise import JobHooks, SupervisorLimits, supervise

    from e2e.agent_bed import DEV_MOUNTS, PYTHONPATH

    submitted = time.monotonic()
    spec = resolve_spec(embodiment=None, preset="so101", task=None, grace_seconds=5)
    run_dir = Path(tempfile.mkdtemp(prefix="armnet-bench-run-"))
    hooks = JobHooks()
    with LocalCell(spec, run_dir, on_grace_expired=hooks.kill_now.set) as cell:
        hooks.on_deadline = cell.pass_deadline
        env = build_job_env(spec, cell.layout, job_id=uuid.uuid4().hex, timeout_seconds=120, args={})
        env.update(PATH=f"{sys.prefix}/bin:/usr/local/bin:/usr/bin:/bin", PYTHONPATH=PYTHONPATH)
        job = ContainerJob.start(client, image, script, env, run_dir, extra_mounts={m: m for m in DEV_MOUNTS})
        running = time.monotonic()
        try:
            result = supervise(job, SupervisorLimits(timeout_seconds=120, grace_seconds=5), hooks)
        finally:
            job.remove()
    done = time.monotonic()
    if result.status.value != "succeeded":
        raise RuntimeError(f"the baseline job ended {result.status.value}: {result.error} {result.stderr[-2000:]}")
    return {"running_s": running - submitted, "result_s": done - submitted}


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))]


def dispatch(args: argparse.Namespace) -> None:
    import tempfile
    from pathlib import Path
    from types import SimpleNamespace

    from armnet_testbed.kube import ControlPlane
    from kubernetes import client as kube_client

    from e2e.agent_bed import AgentBed

    script_dir = Path(tempfile.mkdtemp(prefix="armnet-bench-job-"))
    script = script_dir / "main.py"
    script.write_text(TRIVIAL)
    results: dict[str, list[dict[str, float]]] = {"armnet run --image": [], CONTAINER_PATH: []}
    with services(args) as (client, base_url, image, nats_url), ExitStack() as stack:
        plane = ControlPlane().start()
        stack.callback(plane.stop)
        engine = SimpleNamespace(client=client, base_url=base_url)
        api_client = plane.api_client()
        api = kube_client.CustomObjectsApi(api_client)
        # One namespace and one operator for both agents (an operator limited to its namespace would take
        # the other's claimed cells for ones whose job is gone); each agent has its node, cell and task.
        namespace = plane.create_namespace("dispatch")
        watch = PhaseWatch(api_client, namespace)
        stack.callback(watch.stop)
        pods = PodStages(api_client, namespace)
        stack.callback(pods.stop)
        beds: dict[str, tuple[Any, str]] = {}
        for path in (CONTAINER_PATH, *(() if args.no_node else (POD_PATH,))):
            bed = AgentBed(plane, engine, image, namespace, nats_url=nats_url)
            if path == POD_PATH:
                from armnet_testbed.node import Node

                node = Node(plane=plane).start()
                stack.callback(node.stop)
                # Last in, first out: any pod left is gone before the node stops.
                stack.callback(plane.kubectl, "delete", "pods", "--all", "-n", namespace, "--grace-period=0",
                               "--force", check=False)
                bed.use_pod_launcher(node)
                bed.image_prefix = "armnet-bench-pod"
            stack.callback(bed.stop)
            cell = bed.add_cell("bench")
            if not beds:
                bed.start_operator()
            bed.start_agent()
            bed.wait_ready(cell, timeout=180)
            beds[path] = (bed, bed.image("dispatch-trivial", script))
            results[path] = []
        local_image = beds[CONTAINER_PATH][1]
        load_before = os.getloadavg()[0]
        for index in range(args.rounds + 1):  # round 0 warms every path and is not counted
            taken = {"armnet run --image": local_round(client, local_image, script)}
            for path, (bed, job_image) in beds.items():
                taken[path] = platform_round(bed, api, watch, job_image, f"{'pod' if path == POD_PATH else 'ce'}-{index}",
                                             pods if path == POD_PATH else None)
            if index:
                for path, figures in taken.items():
                    results[path].append(figures)
            print(f"round {index}{' (warm-up)' if not index else ''}: " + "; ".join(
                f"{path} running {r['running_s']:.2f} s result {r['result_s']:.2f} s" for path, r in taken.items()),
                flush=True)
        load_after = os.getloadavg()[0]

    base = results["armnet run --image"]
    base_p50 = {k: statistics.median(r[k] for r in base) for k in ("running_s", "result_s")}
    print(f"\ndispatch: a trivial job on a warm image, {args.rounds} round(s) alternated; "
          f"load average {load_before:.1f} before, {load_after:.1f} after")
    print(f"{'path':<28} {'running p50':>11} {'p99':>6} {'result p50':>10} {'p99':>6} "
          f"{'running vs base':>15} {'result vs base':>14}")
    for path, runs in results.items():
        running = [r["running_s"] for r in runs]
        result = [r["result_s"] for r in runs]
        print(f"{path:<28} {statistics.median(running):>11.2f} {percentile(running, 0.99):>6.2f} "
              f"{statistics.median(result):>10.2f} {percentile(result, 0.99):>6.2f} "
              f"{statistics.median(running) / base_p50['running_s']:>14.2f}x "
              f"{statistics.median(result) / base_p50['result_s']:>13.2f}x")
    if results.get(POD_PATH):
        print(f"{POD_PATH}, where submit -> running goes (p50 of when the bench's pod watch first saw each stage):")
        for stage in PodStages.STAGES:
            times = [r[f"stage:{stage}"] for r in results[POD_PATH] if f"stage:{stage}" in r]
            if times:
                print(f"  {stage:<24} {statistics.median(times):>6.2f} s  (p99 {percentile(times, 0.99):.2f} s)")
    for path in (p for p in (CONTAINER_PATH, POD_PATH) if p in results):
        agent_p50 = statistics.median(r["running_s"] for r in results[path])
        print(f"target ({path}): submit -> running p50 < {TARGET_RUNNING_P50_S:.0f} s: "
              + ("met" if agent_p50 < TARGET_RUNNING_P50_S else "NOT met") + f" ({agent_p50:.2f} s)")


# ---------------------------------------------------------------- part 2 (logs)


def subscriber(url: str, subject: str, expected: int, idle_s: float) -> None:
    """Child mode: audit the lines on ``subject`` from the first (one per message id); print one JSON line."""
    import nats
    from armnet_core.logbatch import split_lines
    from nats.js.api import ConsumerConfig, DeliverPolicy

    async def run() -> dict[str, Any]:
        seen: set[str] = set()
        audit = LineAudit()
        counts = {"messages": 0, "first_at": 0.0, "last_at": 0.0}
        complete = asyncio.Event()
        activity = asyncio.Event()

        async def on_message(msg: Any) -> None:  # a callback: next_msg() costs several times more
            counts["messages"] += 1
            activity.set()
            msg_id = (msg.headers or {}).get("Nats-Msg-Id", "")
            if msg_id not in seen:
                seen.add(msg_id)
                for _, line in split_lines(msg.data, msg.headers):  # one line, or a batch of them
                    if audit.feed(line.decode(errors="replace")):
                        counts["last_at"] = time.time()
                        counts["first_at"] = counts["first_at"] or counts["last_at"]
                if len(audit.indices) >= expected:
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
        return {"whole": len(audit.indices), **audit.report(expected), **counts}

    print(json.dumps(asyncio.run(run())), flush=True)


def start_container(client: Any, image: str, lines: int, read_log_file: bool = True) -> Any:
    """The printing container on the agent's follow path (``ContainerJob``; ``read_log_file=False``:
    the Docker API's follow, the fallback)."""
    try:
        from armnet_launch.container import ULIMITS, ContainerJob
    except ImportError:  # before the launch/ refactor
        from armnet_local.container import ULIMITS, ContainerJob
    from docker.types import Ulimit

    container = client.containers.create(
        image, command=["python3", "-c", PRINTER.format(lines=lines, pad=LINE_PAD)],
        network_mode="host", ulimits=[Ulimit(name=n, soft=s, hard=h) for n, s, h in ULIMITS],
        labels={"armnet.io/bench": "dispatch"}, detach=True,
    )
    container.start()
    job = ContainerJob(client, container)
    job.read_log_file = read_log_file
    return job


def follow(job: Any, on_line: Any) -> None:
    """The agent's reading of a job's output: the supervisor, its line splitting and classification."""
    from armnet_launch.supervise import JobHooks, SupervisorLimits, supervise

    counters: dict[str, int] = {}

    def on_event(event: Any) -> None:
        stream = event.stream.value
        seq = counters.get(stream, 0)
        counters[stream] = seq + 1
        on_line(stream, seq, event.text)

    supervise(job, SupervisorLimits(timeout_seconds=600, grace_seconds=5), JobHooks(on_event=on_event))


def run_follow(client: Any, image: str, lines: int, read_log_file: bool = True) -> dict[str, float]:
    audit = LineAudit()
    first_at, last_at = [0.0], [0.0]

    def on_line(stream: str, seq: int, text: str) -> None:
        if stream == "stdout" and audit.feed(text):
            last_at[0] = time.time()
            first_at[0] = first_at[0] or last_at[0]

    job = start_container(client, image, lines, read_log_file)
    try:
        follow(job, on_line)
        # The supervisor reads the output to its end (bounded by a stall); this waits only
        # for a reader that gave up.
        while len(audit.indices) < lines and time.time() - max(last_at[0], first_at[0]) < IDLE_S:
            time.sleep(0.05)
    finally:
        job.remove()
    return {"lines_per_s": rate(len(audit.indices), first_at[0], last_at[0]), **audit.report(lines)}


def rate(count: int, first_at: float, last_at: float) -> float:
    """Lines per second from the first line seen to the last (container start-up left out)."""
    return (count - 1) / (last_at - first_at) if count > 1 and last_at > first_at else 0.0


def run_nats(client: Any, image: str, lines: int, nats_url: str) -> dict[str, float]:
    from armnet_node.streams import JobStream, NatsLink, StreamSettings

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
    whole = int(report.get("whole", 0))
    return {
        "lines_per_s": rate(whole, float(report.get("first_at", 0.0)), float(report.get("last_at", 0.0))),
        "lost": float(report.get("lost", lines)), "fragments": float(report.get("fragments", 0)),
        "duplicates": float(report.get("duplicates", 0)), "late": float(report.get("late", 0)),
        "dropped": link.dropped,
    }


@contextmanager
def services(args: argparse.Namespace) -> Iterator[tuple[Any, str, str, str]]:
    """(Docker client, its URL, base image, NATS URL): given ones, or the test bed's started for this run."""
    with ExitStack() as stack:
        nats_url = args.nats_url
        if nats_url is None:
            from armnet_testbed.natsd import NatsServer

            nats_url = stack.enter_context(NatsServer()).url
        if os.environ.get("DOCKER_HOST"):
            import docker

            base_url = os.environ["DOCKER_HOST"]
            client = docker.DockerClient(base_url=base_url, timeout=None)
        else:
            from armnet_testbed.podman import PodmanService

            service = PodmanService().start()
            stack.callback(service.stop)
            client, base_url = service.client, service.base_url
        from armnet_testbed.images import BASE_IMAGE, require_base_image

        require_base_image(client)
        yield client, base_url, BASE_IMAGE, nats_url


def log_throughput(args: argparse.Namespace) -> None:
    results: dict[str, list[dict[str, float]]] = {"follow": [], "api": [], "nats": []}
    with services(args) as (client, _, image, nats_url):
        for _ in range(args.rounds):  # the modes take turns, so all see the same machine load
            results["follow"].append(run_follow(client, image, args.lines))
            results["api"].append(run_follow(client, image, args.lines, read_log_file=False))
            results["nats"].append(run_nats(client, image, args.lines, nats_url))

    baseline = statistics.median(r["lines_per_s"] for r in results["follow"])
    print(f"\nlog throughput: {args.lines} lines x {args.rounds} round(s), median per mode")
    print("(lost: printed lines never seen whole; fragments: cut lines seen; late: whole lines seen after a "
          "later one; the worst round)")
    print(f"{'mode':<8} {'lines/s':>10} {'lost':>6} {'frags':>6} {'dups':>6} {'late':>6} {'vs follow':>10}   target")
    for mode, runs in results.items():
        rate = statistics.median(r["lines_per_s"] for r in runs)
        worst = {k: max(int(r[k]) for r in runs) for k in ("lost", "fragments", "duplicates", "late")}
        target = "(baseline)" if mode == "follow" else "(the Docker API's follow: the fallback)" if mode == "api" else (
            f">= {TARGET_LINES_PER_S} lines/s, 0 lost: "
            + ("met" if rate >= TARGET_LINES_PER_S and worst["lost"] == 0 else "NOT met"))
        print(f"{mode:<8} {rate:>10.0f} {worst['lost']:>6} {worst['fragments']:>6} {worst['duplicates']:>6} "
              f"{worst['late']:>6} {rate / baseline:>9.2f}x   {target}")
    dropped = max(int(r.get("dropped", 0)) for r in results["nats"])
    print(f"NatsLink dropped (max over rounds): {dropped}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--lines", type=int, default=100_000)
    parser.add_argument("--rounds", type=int, default=None,
                        help="rounds per mode (default: 1 for the log throughput, 10 for --dispatch)")
    parser.add_argument("--dispatch", action="store_true", help="part 1: submit -> running / result")
    parser.add_argument("--no-node", action="store_true",
                        help="--dispatch without the pod launcher (it needs the test bed's node: root, its lock)")
    parser.add_argument("--nats-url", default=None, help="an existing nats-server -js (default: start one)")
    parser.add_argument("--subscribe", nargs=3, metavar=("URL", "SUBJECT", "N"), help=argparse.SUPPRESS)
    parser.add_argument("--idle", type=float, default=IDLE_S, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.subscribe:
        url, subject, count = args.subscribe
        subscriber(url, subject, int(count), args.idle)
        return
    if args.dispatch:
        args.rounds = args.rounds or 10
        dispatch(args)
        return
    args.rounds = args.rounds or 1
    log_throughput(args)


if __name__ == "__main__":
    main()
