"""The customer's client end to end: ``execute()``, ``logs -f``, heartbeats, teleop, per-namespace NATS.

Real kube-apiserver + etcd, the real ``armnet operator`` and ``armnet agent``
processes (``e2e.agent_bed.AgentBed``), real Podman containers on the cell
simulator, the real nats-server; the client runs as a user runs it, as a library
(``Client``) or as the ``armnet`` command in a process of its own. One bed for
the module, two SO-101 cells.
"""

from __future__ import annotations

import asyncio
import io
import json
import os
import pty
import re
import signal
import subprocess
import sys
import time
import urllib.request
import uuid
from collections.abc import Iterator
from typing import Any

import pytest
from armnet_client import Client, NatsForbidden
from armnet_client.logstream import FollowSettings, follow_events
from armnet_client.logwire import LogLine
from armnet_core.api import FOLLOWER_TIMEOUT_ANNOTATION, TERMINAL_PHASES
from armnet_core.models import JobSpec, JobStatus, RemoteExecutionError
from armnet_testbed.natsd import NatsServer

from e2e.agent_bed import EXAMPLES, JOBS, PYTHONPATH, AgentBed
from tests.support.pty_screen import Screen

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(600)]

RAISES = """
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        print("about to fail", flush=True)
        raise ValueError("the gripper saw no cube")
"""

#: Prints ``lines`` numbered lines, 50 at a time, so the stream is still flowing when NATS restarts.
PRINTS_LINES = """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        lines = int(ctx.args.get("lines", 10000))
        for i in range(lines):
            print(f"line {i:05d}", flush=i % 50 == 49)
            if i % 50 == 49:
                time.sleep(float(ctx.args.get("pause", 0.04)))
        return {"lines": lines}
"""

#: A LeRobot follower driven by the teleop channel until the operator stops recording.
TELEOP_FOLLOWER = """
    import time
    from armnet_runtime import Context, main
    from lerobot.robots.so_follower import SO101Follower, SO101FollowerConfig

    def connected(ctx):
        # configure() writes ~50 registers with LeRobot's default of no retry; on this loaded
        # 2-core test host the simulator now and then misses a status packet, as a real bus can.
        for attempt in range(3):
            robot = SO101Follower(SO101FollowerConfig(
                port=ctx.cell.robot_port, id=ctx.cell.robot_id, calibration_dir=ctx.cell.calibration_dir,
                max_relative_target=ctx.cell.safety_limit))
            try:
                robot.connect()
                return robot
            except (ConnectionError, RuntimeError) as exc:  # RuntimeError: a motor missed the ping
                print(f"connect attempt {attempt + 1} failed: {exc}", flush=True)
                try:
                    robot.bus.disconnect(disable_torque=False)
                except Exception:
                    pass
        raise ConnectionError("the follower did not connect in 3 attempts")

    def retried(call, *args):
        for attempt in range(3):  # likewise every read (send_action reads first, to clamp)
            try:
                return call(*args)
            except ConnectionError:
                if attempt == 2:
                    raise

    def pan(robot, ctx=None):
        observation = retried(robot.get_observation)
        if ctx is not None:  # reported back: `armnet teleop` shows it as the follower's state
            ctx.log_rerun_data(observation=observation)
        return float(observation["shoulder_pan.pos"])

    @main
    def run(ctx: Context):
        robot = connected(ctx)
        try:
            start = pan(robot)
            ctx.report_progress("teleop ready")
            events, actions, last, moved = [], 0, None, 0.0
            deadline = time.monotonic() + float(ctx.args.get("seconds", 60))
            while time.monotonic() < deadline:
                event = ctx.cell.get_teleop_event()
                if event:
                    events.append(event)
                    if event == "stop_recording":
                        break
                action = ctx.cell.get_teleop_action()
                if action:
                    retried(robot.send_action, action)
                    actions += 1
                    last = action
                now = pan(robot, ctx)
                moved = max(moved, abs(now - start))
                time.sleep(1 / 30)
            if last is not None:
                for _ in range(15):  # the last action, held: the follower settles on it
                    retried(robot.send_action, last)
                    time.sleep(1 / 30)
            reached = pan(robot)
        finally:
            try:
                robot.disconnect()
            except ConnectionError as exc:  # the connector turns torque off after the job anyway
                print(f"disconnect: {exc}", flush=True)
        return {"start": start, "reached": reached, "moved": moved, "actions": actions, "events": events,
                "last_action": last}
"""


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str, nats_server: str) -> Iterator[AgentBed]:
    namespace = k8s.create_namespace("client-e2e")
    bed = AgentBed(k8s, podman, base_image, namespace, nats_url=nats_server)
    cells = [bed.add_cell("so101-a"), bed.add_cell("so101-b")]
    bed.start_operator()
    bed.start_agent()
    try:
        for cell in cells:
            # The first health probe imports LeRobot: minutes on this 2-core host under the suite's load.
            bed.wait_ready(cell, timeout=240)
        yield bed
    finally:
        bed.stop()
        k8s.delete_namespace(namespace)


def client_of(bed: AgentBed) -> Client:
    return Client(namespace=bed.namespace, kubeconfig=str(bed.k8s.kubeconfig), nats_url=bed.nats_url, env={})


def armnet(bed: AgentBed, *args: str, **popen: Any) -> subprocess.Popen[bytes]:
    """``armnet <args>`` as a user runs it: a process of its own (``python -m armnet_client``)."""
    argv = [sys.executable, "-m", "armnet_client", *args, "--kubeconfig", str(bed.k8s.kubeconfig),
            "-n", bed.namespace, "--nats-url", str(bed.nats_url)]
    env = {**os.environ, "PYTHONPATH": PYTHONPATH}
    popen.setdefault("stdout", subprocess.PIPE)
    popen.setdefault("stderr", subprocess.PIPE)
    return subprocess.Popen(argv, env=env, **popen)


def spec(bed: AgentBed, image: str, **fields: Any) -> JobSpec:
    return JobSpec(image=image, embodiment="lerobot/so-101", task=bed.node, **fields)


def ready_or_ended(bed: AgentBed, name: str) -> dict[str, Any] | None:
    """The job's status once its progress says it is ready, or once it ended (then the test fails on it)."""
    st = bed.job(name).get("status") or {}
    return st if st.get("progress") == "teleop ready" or st.get("phase") in TERMINAL_PHASES else None


def phase(bed: AgentBed, name: str) -> str | None:
    return (bed.job(name).get("status") or {}).get("phase")


# ------------------------------------------------------------------ execute()


def test_execute_of_the_bus_loop_example_returns_its_result_with_the_return_value(bed: AgentBed) -> None:
    image = bed.image("bus-loop", EXAMPLES / "bus_loop.py", (EXAMPLES / "_so101_moves.py",))
    out = io.StringIO()
    result = client_of(bed).execute(spec(bed, image, args={"degrees": 4}, timeout_seconds=240), out=out,
                                    err=io.StringIO())
    result.raise_for_status()
    assert result.status is JobStatus.SUCCEEDED, result
    assert result.exit_code == 0
    assert set(result.return_value["final_positions"]) >= {"shoulder_pan", "shoulder_lift", "elbow_flex"}
    # What execute() printed while it followed is the result's stdout (read from the stream).
    assert result.stdout and result.stdout == out.getvalue()


def test_execute_of_a_failing_job_raises_the_remote_traceback(bed: AgentBed) -> None:
    # A generous timeout: under the suite's load the interpreter's start alone can take a minute.
    result = client_of(bed).execute(spec(bed, bed.image("raises", RAISES), timeout_seconds=300), out=io.StringIO(),
                                    err=io.StringIO())
    assert result.status is JobStatus.FAILED
    with pytest.raises(RemoteExecutionError) as caught:
        result.raise_for_status()
    assert "ValueError: the gripper saw no cube" in str(caught.value.result.traceback)
    assert "about to fail" in result.stdout


def test_submit_of_an_image_the_node_lacks_says_on_the_terminal_why_it_failed_before_it_started(
    bed: AgentBed,
) -> None:
    submit = armnet(bed, "submit", "--image", "localhost/no-such-image:404", "--embodiment", "lerobot/so-101",
                    "--task", bed.node, "--name", "no-such-image")
    out, err = submit.communicate(timeout=300)
    reason = "image localhost/no-such-image:404 not found on this node; push it to a registry the node can pull from"
    assert submit.returncode == 1, err.decode()
    assert out.decode().split() == ["no-such-image"]
    assert f"[status: failed] {reason}" in err.decode()
    # The agent said it on the job's stream (what `armnet submit` followed), not only in its status.
    uid = bed.job("no-such-image")["metadata"]["uid"]
    ends = [(e.terminal_phase, e.reason) for e in follow_events(FollowSettings(str(bed.nats_url)), bed.namespace, uid,
                                                                follow=False)
            if isinstance(e, LogLine) and e.kind == "status"]
    assert ends == [("failed", reason)]


# ------------------------------------------------------------------ logs -f


def test_logs_follow_gets_ten_thousand_lines_once_and_in_order_across_a_nats_restart(
    bed: AgentBed, nats_service: NatsServer
) -> None:
    client = client_of(bed)
    job = client.submit(spec(bed, bed.image("prints-lines", PRINTS_LINES), args={"lines": 10_000},
                             timeout_seconds=300, detach=True), name="ten-thousand")
    bed.wait_phase(job.id, ("running", "succeeded", "failed"), timeout=180)
    got: list[str] = []
    restarted_at: int | None = None
    for line in client.logs(job.id, follow=True):
        if line.kind == "stdout" and line.text.startswith("line "):
            got.append(line.text)
        if restarted_at is None and len(got) >= 3_000:
            restarted_at = len(got)
            nats_service.restart()  # the agent spools and resends, the follower resumes after its last line
    assert restarted_at is not None
    assert got == [f"line {i:05d}" for i in range(10_000)]
    assert phase(bed, job.id) == "succeeded"


# ------------------------------------------------------------------ heartbeats


def test_a_followed_job_is_cancelled_when_its_client_is_killed_and_a_detached_one_keeps_running(
    bed: AgentBed,
) -> None:
    image = bed.image("counts", JOBS / "counts_slowly.py")
    window = 5
    logs = {name: open(bed.log_dir / f"client-{name}.log", "wb") for name in ("followed", "watcher")}  # noqa: SIM115
    followed = armnet(bed, "submit", "--image", image, "--embodiment", "lerobot/so-101", "--task", bed.node,
                      "--args", '{"lines": 400, "pause": 0.25}', "--timeout", "200", "--name", "followed",
                      "--follower-timeout", str(window), stdout=logs["followed"], stderr=logs["followed"])
    detached = armnet(bed, "submit", "--detach", "--image", image, "--embodiment", "lerobot/so-101",
                      "--task", bed.node, "--args", '{"lines": 240, "pause": 0.25}', "--timeout", "200",
                      "--name", "detached")
    assert detached.wait(60) == 0, detached.stderr.read() if detached.stderr else ""
    watcher = armnet(bed, "logs", "-f", "detached", stdout=logs["watcher"], stderr=logs["watcher"])
    try:
        # The followed client runs beside the detached one: on a loaded host it may create its job later.
        bed.wait(lambda: bed.job_exists("followed"), timeout=60, what="the followed client to create its job")
        assert bed.job("followed")["metadata"]["annotations"][FOLLOWER_TIMEOUT_ANNOTATION] == "5"
        assert "annotations" not in bed.job("detached")["metadata"]
        for name in ("followed", "detached"):
            bed.wait_phase(name, ("running",), timeout=180)
        time.sleep(window + 2)  # longer than the window: the beats keep the followed job alive
        assert phase(bed, "followed") == "running"
        followed.send_signal(signal.SIGKILL)
        watcher.send_signal(signal.SIGKILL)
        killed = time.monotonic()
        st = bed.wait_phase("followed", timeout=60)["status"]
        # window + the agent's check + the cell's 3 s grace, with room for a loaded machine
        assert time.monotonic() - killed < window + 3 + 10
        assert st["phase"] == "cancelled", json.dumps(st)[:2000]
        assert "sent no heartbeat" in st["result"]["error"] and "detach: true" in st["result"]["error"]
        assert phase(bed, "detached") == "running"  # its follower died too, and it does not care
        assert bed.wait_phase("detached", timeout=120)["status"]["phase"] == "succeeded"
        metrics = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
        assert re.search(r"^armnet_agent_follower_cancels_total 1\.0$", metrics, re.M), metrics
    finally:
        for proc in (followed, watcher):
            if proc.poll() is None:
                proc.kill()
            proc.wait(10)
        for log in logs.values():
            log.close()


# ------------------------------------------------------------------ teleop


def test_teleop_with_the_simulated_leader_moves_the_follower_and_keys_reach_the_job(bed: AgentBed) -> None:
    client = client_of(bed)
    job = client.submit(spec(bed, bed.image("teleop", TELEOP_FOLLOWER), args={"seconds": 90},
                             timeout_seconds=180, detach=True), name="teleop")
    ready = bed.wait(lambda: ready_or_ended(bed, job.id), 180, "the teleop job to connect its follower")
    assert ready.get("progress") == "teleop ready", json.dumps(ready)[:3000]
    master, slave = pty.openpty()
    leader = armnet(bed, "teleop", job.id, "--leader", "sim", "--rate", "30",
                    stdin=slave, stdout=slave, stderr=slave, close_fds=True)
    os.close(slave)
    screen = Screen(master)
    try:
        bed.wait(lambda: b"actions sent" in screen.text, 120, "armnet teleop to send actions")
        time.sleep(4)  # half a period of the simulated leader's sines
        bed.wait(lambda: b"follower (" in screen.text, 60, "the follower's state, as the job reports it")
        for key in (b"\x1b[C", b"\x1b[D"):  # Right: next_episode, Left: rerecord_episode
            os.write(master, key)
            time.sleep(0.4)
        os.write(master, b"\x1b")  # Esc: stop_recording, and the session ends
        assert leader.wait(30) == 0, screen.text[-2000:]
    finally:
        if leader.poll() is None:
            leader.kill()
        os.close(master)
    st = bed.wait_phase(job.id, timeout=60)["status"]
    assert st["phase"] == "succeeded", json.dumps(st)[:3000]
    value = st["result"]["returnValue"]
    assert value["events"] == ["next_episode", "rerecord_episode", "stop_recording"]
    # ~140 at 30 Hz on a quiet host; 29 arrived at load 15+. What matters is that a stream of
    # actions reaches the job and the follower tracks them (the two checks below).
    assert value["actions"] >= 10
    assert value["moved"] > 2.0  # the leader's sines moved the follower
    assert abs(value["reached"] - value["last_action"]["shoulder_pan.pos"]) < 2.0  # and it follows


# ------------------------------------------------------------------ per-namespace NATS


@pytest.fixture(scope="module")
def chart_nats(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A nats-server running the chart's rendered nats.conf (tenants team-a and team-b); its host:port."""
    from tests.support.helm_nats import chart_nats_server

    with chart_nats_server(tmp_path_factory.mktemp("chart-nats")) as port:
        yield f"127.0.0.1:{port}"


@pytest.fixture(scope="module")
def published(chart_nats: str) -> Iterator[dict[str, str]]:
    """One job per namespace whose lines the agent's own publisher put in the stream (agent credentials)."""
    from armnet_node.streams import JobStream, NatsLink, StreamSettings

    link = NatsLink(StreamSettings(url=f"nats://agent:agent-pw@{chart_nats}")).start()
    jobs = {"team-a": uuid.uuid4().hex, "team-b": uuid.uuid4().hex}
    try:
        for namespace, uid in jobs.items():
            stream = JobStream(link, namespace, uid)
            for seq in range(1, 4):
                stream.line("stdout", seq, f"{namespace} line {seq}")
            stream.status("succeeded", {"exitCode": 0})
        deadline = time.monotonic() + 30
        while (link.pending or not link.connected) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert link.pending == 0, "the agent's lines never reached the chart's NATS"
        yield jobs
    finally:
        link.stop()


def read_logs(chart_nats: str, user: str, password: str, namespace: str, uid: str) -> list[str]:
    settings = FollowSettings(f"nats://{user}:{password}@{chart_nats}", fetch_timeout_s=0.5)
    return [e.text for e in follow_events(settings, namespace, uid, follow=False) if isinstance(e, LogLine)]


def test_a_tenants_client_reads_its_own_namespaces_logs_with_its_nats_user(
    chart_nats: str, published: dict[str, str]
) -> None:
    lines = read_logs(chart_nats, "tenant-team-a", "a-pw", "team-a", published["team-a"])
    assert lines[:3] == ["team-a line 1", "team-a line 2", "team-a line 3"]


def test_a_tenants_client_cannot_read_another_namespaces_logs(chart_nats: str, published: dict[str, str]) -> None:
    with pytest.raises(NatsForbidden, match="namespace 'team-b'"):
        read_logs(chart_nats, "tenant-team-a", "a-pw", "team-b", published["team-b"])


def test_a_tenants_heartbeats_reach_the_agent_only_for_its_own_namespace(chart_nats: str) -> None:
    """The agent (its own user) hears team-a's beats on team-a's job; team-a cannot beat for team-b."""
    import nats
    from armnet_client.heartbeat import HeartbeatSender

    async def listen(seconds: float) -> list[str]:
        agent = await nats.connect(f"nats://agent:agent-pw@{chart_nats}")
        sub = await agent.subscribe("clients.>")
        await agent.flush()
        own = HeartbeatSender(f"nats://tenant-team-a:a-pw@{chart_nats}", "team-a", "job-a", 0.2).start()
        other = HeartbeatSender(f"nats://tenant-team-a:a-pw@{chart_nats}", "team-b", "job-b", 0.2).start()
        got: list[str] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                got.append((await sub.next_msg(timeout=0.2)).subject)
            except nats.errors.TimeoutError:
                continue
        own.stop()
        other.stop()
        await agent.close()
        return got

    got = asyncio.run(listen(1.5))
    assert "clients.team-a.job-a.heartbeat" in got
    assert "clients.team-b.job-b.heartbeat" not in got

