"""The node agent end to end: ``kubectl apply`` a RobotJob, read its result from the status.

Real kube-apiserver + etcd, the real ``armnet operator`` and ``armnet agent``
processes, real Podman containers, the cell simulator driven by the real
LeRobot/Feetech stack through the connector. One bed per module: the jobs of
independent scenarios are submitted together at the start (they run side by
side on the bed's cells) and each test then checks its own job's status.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from armnet_client import Client
from armnet_core.api import ACTIVE_PHASES, JOB_UID_LABEL, SIM_UNPLUG_ANNOTATION
from armnet_core.times import status_time

from e2e import scenarios
from e2e.agent_bed import EXAMPLES, JOBS, AgentBed
from e2e.scenarios import seconds_between, status

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(900)]

#: The timeout of the timeout scenarios: the SDK's start-up (imports) took over 40 s with three sessions
#: and an image build on the 2-core VM.
JOB_TIMEOUT = 60
#: The recording cell's grace window (seconds): see the ``bed`` fixture.
RECORDING_GRACE = 20
#: How long the agent may take to see a cancel (watch event, then its pass) on the loaded 2-core VM.
CANCEL_SEEN_S = 1.5

HONOURS_SHUTDOWN = """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        print("started", flush=True)
        rounds = 0
        while not ctx.cell.is_shutting_down():
            rounds += 1
            time.sleep(0.1)
        return {"stopped_cleanly": True}
"""

RESETS = """
    import time
    from armnet_runtime import Context, main

    @main
    def run(ctx: Context):
        ctx.report_progress("resetting")
        started = time.monotonic()
        ctx.cell.reset()
        waited = time.monotonic() - started
        ctx.report_progress("waiting for the outcome")
        deadline = time.monotonic() + 120
        outcome = ctx.cell.is_complete()
        while not outcome.complete and time.monotonic() < deadline:
            time.sleep(0.1)
            outcome = ctx.cell.is_complete()
        return {"reset_waited_s": waited, "complete": outcome.complete, "success": outcome.success}
"""


def target_completion() -> dict[str, Any]:
    """The cell's monitor looks for the simulator's end-effector disc on its target pad."""
    from armnet_sim.render import target_region

    left, top, width, height = target_region(640, 480)
    return {"camera": "front", "region": {"left": left, "top": top, "width": width, "height": height},
            "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80},
            "consecutiveFrames": 3, "rateHz": 15}


TARGET_COMPLETION = target_completion()


@pytest.fixture(scope="module")
def outputs_bucket(object_store: Any) -> str:
    return str(object_store.create_bucket("agent-e2e-outputs"))


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str, nats_server: str, object_store: Any,
        outputs_bucket: str) -> Iterator[AgentBed]:
    namespace = k8s.create_namespace("agent-e2e")
    bed = AgentBed(k8s, podman, base_image, namespace, nats_url=nats_server)
    bed.agent_env = object_store.agent_env(outputs_bucket)
    bed.cells = [bed.add_cell("so101-a"), bed.add_cell("so101-b")]  # type: ignore[attr-defined]
    bed.bimanual = bed.add_cell("bimanual", bimanual=True)  # type: ignore[attr-defined]
    # Its own task, so only the evaluation lands on it (its monitor scores frames all along).
    bed.monitored = bed.add_cell(  # type: ignore[attr-defined]
        "monitored", task="evaluation", completion=TARGET_COMPLETION,
        cameras={"front": {"indexOrPath": 0, "width": 640, "height": 480, "fps": 30}})
    # The recording cut by its timeout: a cell of its own with a grace window that lets LeRobot's
    # record() close its dataset and the job's interpreter end (the other cells' 3 s serve the
    # kill tests). From the interlock's trip to the process's end took 0.8 s here, the job's
    # traceback printed at 0.1 s; ten times that on the loaded host (docs/testing.md, "A loaded
    # host"), where 3 s cut CI run 40's job short before its traceback.
    bed.recorder = bed.add_cell("recorder", task="recording", grace=RECORDING_GRACE)  # type: ignore[attr-defined]
    bed.start_operator()
    bed.start_agent()
    try:
        for cell in [*bed.cells, bed.bimanual, bed.monitored, bed.recorder]:  # type: ignore[attr-defined]
            bed.wait_ready(cell, timeout=90)
        yield bed
    finally:
        bed.stop()
        k8s.delete_namespace(namespace)


def streamed_end(bed: AgentBed, name: str, messages: int) -> dict[str, Any]:
    """The last of the job's ``messages`` status messages on its stream: the agent says there why it ended."""
    uid = bed.job(name)["metadata"]["uid"]
    return json.loads(stream_lines(bed.nats_url, f"logs.{bed.namespace}.{uid}.status", messages)[-1])


@pytest.fixture(scope="module")
def batch(bed: AgentBed) -> dict[str, str]:
    """The independent scenarios' jobs, submitted together so they run side by side."""
    bus_loop = bed.image("bus-loop", EXAMPLES / "bus_loop.py", (EXAMPLES / "_so101_moves.py",))
    bed.k8s.kubectl("create", "secret", "generic", "api-token", "-n", bed.namespace,
                    "--from-literal=API_TOKEN=s3cr3t-value-123")
    jobs = {
        "success": bed.submit("bus-loop", bus_loop, timeout=240, args={"degrees": 4}),
        "failure": bed.submit("raises", bed.image("raises", JOBS / "raises.py"), timeout=120),
        "missing-secret": bed.submit("no-secret", bed.image("echo", JOBS / "echo.py"), secrets={"API_TOKEN": "absent"}),
        "evaluation": bed.submit("evaluates", bed.image("evaluates", JOBS / "evaluates.py", (EXAMPLES / "_so101_moves.py",)),
                                 task="evaluation", timeout=300),
        "output": bed.submit("writes-output", bed.image("writes-output", JOBS / "writes_output.py"), timeout=120),
        # On the cell with a camera (the evaluation's), after or before the evaluation.
        "recording": bed.submit("records", bed.image("records", EXAMPLES / "record.py", (EXAMPLES / "_so101_moves.py",)), task="evaluation",
                                timeout=300, args={"episodes": 2, "episode_seconds": 2, "fps": 10}),
        # On its own cell, with no camera: the episodes' parquet only. 1000 episodes: the
        # timeout always cuts one. 180 s, not 90: on a loaded host the LeRobot import and
        # record()'s setup can take 90 s, leaving the job in SO101Follower.configure() at such a
        # deadline; at least one episode must finish before the cut.
        "recording-timeout": bed.submit("records-until-timeout", bed.image("records", EXAMPLES / "record.py", (EXAMPLES / "_so101_moves.py",)),
                                        # The job's own start (LeRobot's record() and torch imported in
                                        # its container) counts against its timeout: 160 s to its first
                                        # camera read in a clean-clone run at load ~12 (2026-12-01), and
                                        # a 180 s timeout cut it before any episode. 300 s leaves room.
                                        task="recording", timeout=300,
                                        args={"episodes": 1000, "episode_seconds": 2,
                                                          "reset_seconds": 0.5, "fps": 10}),
        "secret": bed.submit("with-secret", bed.image("echo", JOBS / "echo.py"), args={"size": "x" * 60_000},
                             secrets={"API_TOKEN": "api-token"}),
        "timeout-ignored": bed.submit("ignores", bed.image("ignores", JOBS / "ignores_shutdown.py"), timeout=JOB_TIMEOUT),
        "timeout-honoured": bed.submit("honours", bed.image("honours", HONOURS_SHUTDOWN), timeout=JOB_TIMEOUT),
        "safety": bed.submit("unsafe", bed.image("unsafe", JOBS / "unsafe.py", (EXAMPLES / "_so101_moves.py",)), timeout=180),
        "bimanual": bed.submit("bimanual", bed.image("bimanual", EXAMPLES / "bimanual.py",
                                                     (EXAMPLES / "_so101_moves.py",)),
                               embodiment="lerobot/bimanual_so101", timeout=240),
    }
    return jobs


def test_a_bus_loop_job_succeeds_with_its_return_value_in_status(
    bed: AgentBed, batch: dict[str, str], object_store: Any, outputs_bucket: str,
) -> None:
    st = scenarios.a_bus_loop_job_succeeds_with_its_return_value(bed, batch["success"])
    assert st["progress"]
    # Every output line also went to the job's log subject on NATS, once and in order.
    uid = st["jobId"]
    from armnet_runtime.markers import parse_marker_line

    def is_progress(line: str) -> bool:
        marker = parse_marker_line(line)
        return marker is not None and marker.kind == "progress"

    printed = st["result"]["stdoutTail"].splitlines()
    plain = [line for line in printed if not is_progress(line)]  # progress goes to its own subject
    assert stream_lines(bed.nats_url, f"logs.{bed.namespace}.{uid}.stdout", len(plain)) == plain
    progress = stream_lines(bed.nats_url, f"logs.{bed.namespace}.{uid}.progress", len(printed) - len(plain))
    assert len(progress) == len(printed) - len(plain) > 0
    phases = [json.loads(text)["phase"] for text in stream_lines(bed.nats_url, f"logs.{bed.namespace}.{uid}.status", 2)]
    assert phases[0] == "running" and phases[-1] == "succeeded", phases
    # The job wrote nothing to its output directory: what is stored is the cell's record of it
    # alone, its servo trace, and the directory leaves the robot host.
    bed.wait(lambda: not (bed.state_dir / "outputs" / uid).exists(), 60, "the job's output directory removed")
    artifacts = status(bed.job(batch["success"]))["artifacts"]
    assert (artifacts["phase"], artifacts["complete"]) == ("Uploaded", True), artifacts
    paths = scenarios.a_bus_loop_job_s_servo_trace_is_stored_and_agrees_with_it(st, object_store, outputs_bucket,
                                                                               f"{bed.namespace}/{uid}/")
    assert artifacts["files"] == len(paths) and all(p.startswith("armnet-cell/servo-trace/") for p in paths)


def test_what_a_job_writes_to_its_output_directory_is_stored_with_its_checksums(
    bed: AgentBed, batch: dict[str, str], object_store: Any, outputs_bucket: str,
) -> None:
    # As a customer waits for it: the result says where the output went (the terminal status
    # said Pending, so the client waits for the upload: docs/client.md).
    result = Client(namespace=bed.namespace, kubeconfig=str(bed.k8s.kubeconfig), env={},
                    artifacts_wait_s=120).wait(batch["output"], timeout=420)
    st = status(bed.job(batch["output"]))
    assert st["phase"] == "succeeded", json.dumps(st, indent=1)
    uid = st["jobId"]
    assert result.artifacts is not None and result.artifacts.phase == "Uploaded", result.artifacts
    artifacts = st["artifacts"]
    prefix = f"{bed.namespace}/{uid}/"
    # The job's two files, and the cell's record of the job beside them (its servo trace).
    s3 = object_store.client()
    listed = json.loads(s3.get_object(Bucket=outputs_bucket, Key=prefix + "manifest.json")["Body"].read())["files"]
    own = [f for f in listed if not f["path"].startswith("armnet-cell/")]
    assert (len(own), sum(f["bytes"] for f in own)) == (2, 4096 + 26), own
    record_bytes = sum(f["bytes"] for f in listed) - (4096 + 26)
    assert result.artifacts.model_dump(exclude_none=True) == {
        "phase": "Uploaded", "location": artifacts["location"], "manifest": artifacts["manifest"],
        "files": len(listed), "bytes": 4096 + 26 + record_bytes, "complete": True, "left_out": 1,
        "message": artifacts["message"]}
    assert artifacts["location"] == f"s3://{outputs_bucket}/{prefix}"
    assert (artifacts["files"], artifacts["leftOut"]) == (len(listed), 1), artifacts
    assert "host-hostname: a symbolic link that leads out of the output directory" in artifacts["message"]
    s3 = object_store.client()
    manifest = json.loads(s3.get_object(Bucket=outputs_bucket, Key=prefix + "manifest.json")["Body"].read())
    episode = s3.get_object(Bucket=outputs_bucket, Key=prefix + "files/data/chunk-000/episode_000000.parquet")
    data = episode["Body"].read()
    assert data == bytes(range(256)) * 16
    [entry] = [f for f in manifest["files"] if f["path"] == "data/chunk-000/episode_000000.parquet"]
    assert entry["sha256"] == hashlib.sha256(data).hexdigest() == episode["Metadata"]["sha256"]
    assert not (bed.state_dir / "outputs" / uid).exists()


def downloaded_dataset(bed: AgentBed, name: str, repo_id: str, object_store: Any, out: Path,
                       monkeypatch: pytest.MonkeyPatch) -> Any:
    """The job's recorded LeRobot dataset, once stored, fetched with ``armnet artifacts`` and loaded by LeRobot."""
    from armnet_cli.main import main as armnet
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    bed.wait(lambda: (status(bed.job(name)).get("artifacts") or {}).get("phase") == "Uploaded", 180,
             f"{name}'s output uploaded")
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", object_store.access_key)
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", object_store.secret_key)
    monkeypatch.setenv("ARMNET_ARTIFACTS_ENDPOINT", object_store.endpoint)
    assert armnet(["artifacts", name, "--download", str(out),
                   "--kubeconfig", str(bed.k8s.kubeconfig), "-n", bed.namespace]) == 0
    # torchcodec does not load here (docs/lerobot-compatibility.md): video frames are read with PyAV.
    return LeRobotDataset(repo_id, root=out / "lerobot" / repo_id, video_backend="pyav")


def test_lerobots_own_recording_in_a_job_downloads_with_armnet_artifacts_as_a_dataset_lerobot_loads(
    bed: AgentBed, batch: dict[str, str], object_store: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    import av

    st = status(bed.wait_phase(batch["recording"], timeout=600))
    assert st["phase"] == "succeeded", json.dumps(st, indent=1)
    recorded = st["result"]["returnValue"]
    assert (recorded["episodes"], recorded["cameras"]) == (2, ["observation.images.front"]), recorded
    dataset = downloaded_dataset(bed, batch["recording"], recorded["repo_id"], object_store, tmp_path, monkeypatch)
    assert (dataset.num_episodes, dataset.num_frames) == (2, recorded["frames"])
    lengths = list(dataset.meta.episodes["length"])
    assert len(lengths) == 2 and all(n > 0 for n in lengths) and sum(lengths) == recorded["frames"]
    assert len(dataset.hf_dataset[0]["action"]) == 6 and len(dataset.hf_dataset[0]["observation.state"]) == 6
    [video] = (dataset.root / "videos" / "observation.images.front").rglob("*.mp4")
    with av.open(str(video)) as container:
        frames = list(container.decode(video=0))
    assert len(frames) == recorded["frames"] and (frames[0].width, frames[0].height) == (640, 480)
    # The cell's own record came down with it: the camera the job used, as a video that plays,
    # and the servo trace of the arm the recording drove.
    [cell_video] = (tmp_path / "armnet-cell" / "videos").glob("*.mp4")
    with av.open(str(cell_video)) as container:
        cell_frames = list(container.decode(video=0))
    assert cell_frames and (cell_frames[0].width, cell_frames[0].height) == (640, 480), cell_video
    import pyarrow.parquet as pq

    kinds = set(pq.read_table(tmp_path / "armnet-cell" / "servo-trace").column("kind").to_pylist())
    assert {"present_position", "goal_position"} <= kinds, kinds


def test_an_evaluation_nobody_watches_is_judged_by_the_cells_monitor_in_its_status(
    bed: AgentBed, batch: dict[str, str], object_store: Any, outputs_bucket: str,
) -> None:
    st = status(bed.wait_phase(batch["evaluation"], timeout=420))
    assert st["phase"] == "succeeded", json.dumps(st, indent=1)
    assert st["result"]["returnValue"] == {"complete": [True, False]}
    rollouts = st["rollouts"]
    assert [(r["index"], r["outcome"], r.get("markedBy")) for r in rollouts] == [
        (1, "success", "monitor"), (2, "failure", "monitor")], rollouts
    reached, short = (r["monitor"] for r in rollouts)
    assert (reached["outcome"], short["outcome"]) == ("success", "failure")
    assert reached["score"] > 0 and reached["frameAt"] <= reached["at"] <= rollouts[0]["endedAt"]

    # The cell's record of the job, stored with its output: each rollout's pictures and the history.
    bed.wait(lambda: (status(bed.job(batch["evaluation"])).get("artifacts") or {}).get("phase") == "Uploaded", 120,
             "the evaluation's output uploaded")
    prefix = f"{bed.namespace}/{st['jobId']}/files/armnet-cell/"
    stored = object_store.objects(outputs_bucket, prefix)
    pictures = sorted(key[len(prefix):].split("/", 2)[2] for key in stored if key.endswith(".jpg"))
    assert pictures == ["first.jpg", "first.jpg", "last.jpg", "last.jpg", "verdict.jpg", "verdict.jpg"], sorted(stored)
    kept = json.loads(stored[prefix + "rollouts.json"])["rollouts"]
    assert [(r["index"], r["outcome"], r["markedBy"]) for r in kept] == [(1, "success", "monitor"), (2, "failure", "monitor")]


def test_a_job_that_raises_fails_with_its_traceback(bed: AgentBed, batch: dict[str, str]) -> None:
    scenarios.a_job_that_raises_fails_with_its_traceback(bed, batch["failure"])


def test_a_missing_secret_fails_the_job_before_it_starts_naming_the_secret(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    st = status(scenarios.a_missing_secret_fails_the_job_before_it_starts(bed, batch["missing-secret"]))
    end = streamed_end(bed, batch["missing-secret"], 1)
    assert (end["phase"], end["detail"]) == ("failed", {"error": st["result"]["error"]})


def test_secrets_and_a_large_args_object_reach_the_job_and_no_secret_value_reaches_the_status(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    job = bed.wait_phase(batch["secret"], timeout=300)
    st = status(job)
    assert st["phase"] == "succeeded", json.dumps(st)[:3000]
    value = st["result"]["returnValue"]
    assert value["secret_length"] == len("s3cr3t-value-123")
    assert len(value["args"]["size"]) == 60_000
    assert value["job_id"] == job["metadata"]["uid"]
    assert "s3cr3t-value-123" not in json.dumps(job)


def test_a_job_ignoring_shutdown_is_killed_at_the_end_of_grace_and_ends_timeout(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    # The clock runs from the container start: killed within grace (3 s) + 1 s after the deadline.
    st = scenarios.a_job_ignoring_shutdown_is_killed_at_the_end_of_grace(bed, batch["timeout-ignored"],
                                                                         job_timeout=JOB_TIMEOUT, end_seen_s=1)
    end = streamed_end(bed, batch["timeout-ignored"], 2)
    assert (end["phase"], end["detail"]["error"]) == ("timeout", st["result"]["error"])


def test_a_job_honouring_shutdown_ends_timeout_with_its_return_value(bed: AgentBed, batch: dict[str, str]) -> None:
    st = status(bed.wait_phase(batch["timeout-honoured"], timeout=300))
    assert st["phase"] == "timeout", json.dumps(st)[:3000]
    assert st["result"].get("returnValue") == {"stopped_cleanly": True}, json.dumps(st)[:3000]


def test_a_safety_violation_fails_the_job_with_the_connectors_record_and_the_interlock_clears(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    scenarios.a_safety_violation_fails_the_job_and_the_interlock_clears(bed, batch["safety"])


def test_a_bimanual_job_runs_on_the_bimanual_cell(bed: AgentBed, batch: dict[str, str]) -> None:
    scenarios.a_bimanual_job_runs_on_the_bimanual_cell(bed, batch["bimanual"])


def test_a_cancelled_job_ends_cancelled_within_grace_and_the_cell_takes_the_next_job(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    image = bed.image("counts", JOBS / "counts_slowly.py")
    bed.submit("to-cancel", image, args={"lines": 1000, "pause": 0.2}, timeout=300)
    running = bed.wait_phase("to-cancel", ("running",), timeout=300)
    cell = status(running)["cellName"]
    asked = datetime.now(UTC)
    bed.k8s.kubectl("patch", "rj", "to-cancel", "-n", bed.namespace, "--type=merge", "-p", '{"spec":{"cancel":true}}')
    stored = datetime.now(UTC)  # the API server holds the cancel from here on
    st = status(bed.wait_phase("to-cancel", timeout=60))
    assert st["phase"] == "cancelled"
    end = streamed_end(bed, "to-cancel", 2)
    assert (end["phase"], end["detail"]["error"]) == ("cancelled", "the job was cancelled before it finished")
    bed.wait(lambda: not (bed.cell(cell).get("status") or {}).get("currentJob"), 30, f"{cell} released")
    # The job ignores shutdown: it gets the cell's whole grace window (3 s), then the kill
    # within grace + 1 s of the window opening (finishedAt of a killed job is when the kill was
    # sent), and the window opens once the agent has seen the cancel (a watch event, then a
    # pass: 0.1-0.5 s on a quiet VM, up to 1.4 s measured at load average 35).
    assert seconds_between(status_time(asked), st["finishedAt"]) >= 3
    assert seconds_between(status_time(stored), st["finishedAt"]) <= 3 + 1 + CANCEL_SEEN_S, st
    bed.submit("after-cancel", image, args={"lines": 2, "pause": 0.0}, timeout=120)
    after = status(bed.wait_phase("after-cancel", timeout=300))
    assert after["phase"] == "succeeded"


def test_six_jobs_on_two_cells_all_finish_and_never_share_a_cell(bed: AgentBed, batch: dict[str, str]) -> None:
    for key, name in batch.items():
        if key != "recording-timeout":  # on a cell of its own; its test waits for it
            bed.wait_phase(name, timeout=400)  # the batch is done: the two so101 cells are free
    image = bed.image("counts", JOBS / "counts_slowly.py")
    # Created in this order (one apply after the other), one priority: FIFO is this order.
    names = [bed.submit(f"queued-{i}", image, args={"lines": 4, "pause": 0.2}, timeout=120) for i in range(6)]

    def sample() -> bool:
        listed = json.loads(bed.k8s.kubectl("get", "rj", "-n", bed.namespace, "-o", "json").stdout)["items"]
        phases = {job["metadata"]["name"]: status(job).get("phase") for job in listed}
        active: dict[str, list[str]] = {}
        for job in listed:
            st = status(job)
            if st.get("phase") in ACTIVE_PHASES:
                active.setdefault(st.get("cellName", ""), []).append(job["metadata"]["name"])
        assert all(len(v) == 1 for v in active.values()), f"two jobs on one cell: {active}"
        # Strict FIFO: no job has left the queue while one created before it still waits.
        left = [phases.get(name) not in (None, "", "submitted", "queued") for name in names]
        assert left == sorted(left, reverse=True), f"a later job left the queue first: {phases}"
        return all(phases.get(name) == "succeeded" for name in names)

    bed.wait(sample, 600, "six queued jobs to succeed", every=0.2)
    finished = {name: status(bed.job(name)) for name in names}
    by_cell: dict[str, list[str]] = {}
    for name in sorted(names, key=lambda n: finished[n]["startedAt"]):
        by_cell.setdefault(finished[name]["cellName"], []).append(name)
    # On each cell the jobs started in the order they were created.
    assert all(on_cell == sorted(on_cell, key=names.index) for on_cell in by_cell.values()), by_cell
    assert len(by_cell) == 2, by_cell


# Its job runs on a cell of its own until its 300 s timeout, so its test comes late: the
# tests before it check the batch meanwhile. It must end before the agent is killed below
# (the container launcher's connector lives in the agent's process).
def test_a_recording_stopped_at_its_timeout_keeps_every_finished_episode(
    bed: AgentBed, batch: dict[str, str], object_store: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    import re

    st = status(bed.wait_phase(batch["recording-timeout"], timeout=600))
    assert st["phase"] == "timeout", json.dumps(st, indent=1)
    # At the deadline the interlock refuses the next action; record() closes the dataset on its
    # way out, and the job ends on its own within the grace window.
    assert "ShuttingDown" in st["result"].get("traceback", ""), json.dumps(st, indent=1)[-6000:]
    assert st["result"]["exitCode"] == 1, json.dumps(st, indent=1)[-6000:]
    assert f"stopped within the {RECORDING_GRACE} s grace window" in st["result"]["error"], st["result"]["error"]
    started = [int(n) for n in re.findall(r"Recording episode (\d+)", st["result"]["stderrTail"])]
    assert started, st["result"]["stderrTail"][-2000:]
    dataset = downloaded_dataset(bed, batch["recording-timeout"], "armnet/recording", object_store, tmp_path,
                                 monkeypatch)
    cut_short = max(started)  # the episode the deadline cut: LeRobot never saved it
    assert dataset.num_episodes == cut_short >= 1
    lengths = list(dataset.meta.episodes["length"])
    assert list(dataset.meta.episodes["episode_index"]) == list(range(cut_short))
    assert all(n > 0 for n in lengths) and sum(lengths) == dataset.num_frames == len(dataset.hf_dataset)


def test_an_agent_killed_mid_job_readopts_it_and_reports_every_line_once(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    scenarios.an_agent_killed_mid_job_readopts_it_and_reports_every_line_once(bed, lines=60, output_within_s=60)


def test_an_unplugged_servo_makes_the_cell_not_ready_with_a_reason_and_no_job_is_bound(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    task = f"sick-{bed.node}"
    cell = bed.add_cell("sick", task=task)
    bed.wait_ready(cell, timeout=60)
    bed.k8s.kubectl("annotate", "cell", cell, f"{SIM_UNPLUG_ANNOTATION}=arm/elbow_flex", "--overwrite")

    def hardware_down() -> dict[str, Any] | None:
        conditions = {c["type"]: c for c in (bed.cell(cell).get("status") or {}).get("conditions", [])}
        hw = conditions.get("HardwareReady", {})
        return hw if hw.get("status") == "False" else None

    hw = bed.wait(hardware_down, 30, "HardwareReady False")
    assert hw["reason"] == "ServoNotResponding" and "elbow_flex" in hw["message"]
    bed.wait(lambda: (bed.cell(cell).get("status") or {}).get("phase") == "Faulted", 15, "cell Faulted")
    bed.submit("for-sick-cell", bed.image("counts", JOBS / "counts_slowly.py"), task=task, args={"lines": 1})
    queued = bed.wait_phase("for-sick-cell", ("queued",), timeout=30)
    assert status(queued).get("queuedReason") == "AllCellsUnavailable"
    assert not (bed.cell(cell).get("status") or {}).get("currentJob")
    bed.k8s.kubectl("delete", "cell", cell, "--wait=false")


def hardware_ready(bed: AgentBed, cell: str, wanted: str) -> Callable[[], dict[str, Any] | None]:
    def check() -> dict[str, Any] | None:
        conditions = {c["type"]: c for c in (bed.cell(cell).get("status") or {}).get("conditions", [])}
        hw = conditions.get("HardwareReady", {})
        return hw if hw.get("status") == wanted else None
    return check


def test_a_vanished_device_fails_the_running_job_with_device_lost_and_the_cell_recovers_when_it_returns(
    bed: AgentBed,
) -> None:
    import urllib.request

    task = f"unplug-{bed.node}"
    cell = bed.add_cell("unplug", task=task)
    bed.wait_ready(cell, timeout=60)
    # The simulated arm's device path: the agent's symlink to the simulator's pty (as udev's
    # /dev/serial/by-id link to a USB adapter); removing it is pulling the arm's cable.
    link = bed.state_dir / "cells" / cell / "dev" / "arm"
    pty = os.readlink(link)
    bed.submit("loses-device", bed.image("counts", JOBS / "counts_slowly.py"), task=task, args={"lines": 1000, "pause": 0.2},
               timeout=300)
    bed.wait(lambda: status(bed.job("loses-device")).get("progress"), 300, "the job's code running")
    link.unlink()
    unplugged = datetime.now(UTC)
    try:
        hw = bed.wait(hardware_ready(bed, cell, "False"), 20, "HardwareReady False")
        st = status(bed.wait_phase("loses-device", timeout=60))
    finally:
        link.symlink_to(pty)
    assert hw["reason"] == "DeviceLost" and f"arm arm's serial port: {link} does not exist" in hw["message"]
    assert st["phase"] == "failed", json.dumps(st)[:3000]
    assert st["result"]["error"] == f"device lost: arm arm's serial port: {link} does not exist"
    end = streamed_end(bed, "loses-device", 2)
    assert (end["phase"], end["detail"]["error"]) == ("failed", st["result"]["error"])
    # Debounce 1.5 s + a 0.5 s read + the cell's 3 s grace (the job ignores shutdown: killed at its
    # end), not the job's 300 s timeout; the rest is slack for the loaded 2-core VM.
    assert seconds_between(status_time(unplugged), st["finishedAt"]) <= 1.5 + 0.5 + 3 + 10, st
    bed.wait(hardware_ready(bed, cell, "True"), 20, "HardwareReady True again with the device back")
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
    assert "armnet_agent_jobs_device_lost_total 1.0" in text
    bed.k8s.kubectl("delete", "cell", cell, "--wait=false")


def test_the_agent_exports_job_and_heartbeat_metrics(bed: AgentBed, batch: dict[str, str]) -> None:
    import urllib.request

    bed.wait_phase(batch["success"], timeout=300)
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=10).read().decode()
    assert 'armnet_agent_jobs_finished_total{outcome="succeeded"}' in text
    assert "armnet_agent_heartbeat_age_seconds{cell=" in text
    assert "armnet_agent_launch_latency_seconds_count" in text
    # The agent runs beside its Podman: every job's output is read from the engine's log file.
    assert 'armnet_agent_job_log_reads_total{via="file"}' in text
    assert 'armnet_agent_job_log_reads_total{via="engine_api"}' not in text


def test_a_container_that_vanished_while_the_agent_was_down_fails_its_job_with_a_clear_error(
    bed: AgentBed, batch: dict[str, str]
) -> None:
    image = bed.image("counts", JOBS / "counts_slowly.py")
    bed.submit("vanishes", image, args={"lines": 400, "pause": 0.25}, timeout=200)
    job = bed.wait_phase("vanishes", ("running",), timeout=300)
    bed.kill_agent()
    for container in bed.podman.client.containers.list(
        all=True, filters={"label": f"{JOB_UID_LABEL}={job['metadata']['uid']}"}
    ):
        container.remove(force=True)
    bed.start_agent()
    st = status(bed.wait_phase("vanishes", timeout=120))
    assert st["phase"] == "failed"
    assert "vanished" in st["result"]["error"]
    end = streamed_end(bed, "vanishes", 2)  # running, from the first agent; failed, from the second
    assert (end["phase"], end["detail"]) == ("failed", {"error": st["result"]["error"]})


def test_a_nats_outage_mid_job_loses_no_line_and_the_result_still_lands_in_status(
    bed: AgentBed, nats_service: Any
) -> None:
    image = bed.image("counts", JOBS / "counts_slowly.py")
    # Held after line 8 until released: the outage comes mid-job however slowly this test runs.
    job = bed.submit("through-outage", image, args={"lines": 30, "pause": 0.25, "hold_at": 8}, timeout=200)
    uid = bed.job(job)["metadata"]["uid"]
    bed.wait_phase(job, ("running",), timeout=300)
    bed.wait(lambda: line_number(status(bed.job(job)).get("progress")) >= 5, 180, "the first lines")
    nats_service._proc.stop()  # nats-server goes away mid-job (the store stays on disk)
    try:
        assert line_number(status(bed.job(job)).get("progress")) < 29, "the job ended before the outage"
        bed.release(uid)
        # The job prints on, finishes and is reported while NATS is down.
        st = status(bed.wait_phase(job, timeout=120))
    finally:
        nats_service.start()  # same port, same JetStream store
    assert st["phase"] == "succeeded", json.dumps(st)[:3000]
    assert st["result"]["returnValue"] == {"lines": 30}
    # Once NATS is back the agent publishes what it kept: every line once, in order (as
    # printed: the runtime's timestamp prefix, progress markers on their own subject).
    printed = [line for line in st["result"]["stdoutTail"].splitlines() if "[armnet:progress]" not in line]
    published = stream_lines(bed.nats_url, f"logs.{bed.namespace}.{uid}.stdout", len(printed))
    assert published == printed
    assert [line.split(" ", 1)[1] for line in published[:-1]] == [f"line {i:03d}" for i in range(30)]
    progress = stream_lines(bed.nats_url, f"logs.{bed.namespace}.{uid}.progress", 30)
    assert progress == [f"line {i}" for i in range(30)]
    phases = [json.loads(t)["phase"] for t in stream_lines(bed.nats_url, f"logs.{bed.namespace}.{uid}.status", 2)]
    assert phases == ["running", "succeeded"], phases


def test_a_reset_confirmation_and_an_outcome_on_the_cells_fms_subjects_reach_the_running_job(
    bed: AgentBed,
) -> None:
    import asyncio

    import nats

    image = bed.image("resets", RESETS)
    operator = "e2e-cell-operator"

    async def operate() -> str:
        """The cell operator's tool: wait for the reset to be announced, confirm, then report an outcome."""
        assert bed.nats_url is not None
        nc = await nats.connect(bed.nats_url)
        try:
            notices = await nc.subscribe("fms.*.reset.requested")
            await nc.flush()
            job = await asyncio.to_thread(bed.submit, "resets", image, timeout=240)
            uid = (await asyncio.to_thread(bed.job, job))["metadata"]["uid"]
            while True:
                notice = await notices.next_msg(timeout=300)
                if json.loads(notice.data).get("job") == uid:
                    break
            cell = notice.subject.split(".")[1]
            await asyncio.sleep(1.0)  # the job's reset waits for the confirmation meanwhile
            await nc.publish(f"fms.{cell}.reset.confirm", json.dumps({"by": operator, "request": None}).encode())
            await nc.flush()
            await asyncio.to_thread(
                bed.wait, lambda: status(bed.job(job)).get("progress") == "waiting for the outcome", 60,
                "the job to ask for the episode's outcome")
            await nc.publish(f"fms.{cell}.outcome", json.dumps({"success": False, "by": operator}).encode())
            await nc.flush()
            return cell
        finally:
            await nc.close()

    cell = asyncio.run(operate())
    st = status(bed.wait_phase("resets", timeout=120))
    assert st["phase"] == "succeeded", json.dumps(st)[:3000]
    assert st["cellName"] == cell
    value = st["result"]["returnValue"]
    # The reset returned only once confirmed, and the operator's "failure" ended the episode
    # (the simulated cell has no automated scoring: nothing else completes it).
    assert value["reset_waited_s"] >= 1.0, value
    assert value["complete"] is True and value["success"] is False, value


def line_number(progress: str | None) -> int:
    """``line 7`` -> 7: how far a ``jobs/counts_slowly.py`` job is (-1 before its first line)."""
    if not progress or not progress.startswith("line "):
        return -1
    return int(progress.split()[1])


def stream_lines(url: str | None, subject: str, expected: int) -> list[str]:
    """Every line stored on ``subject`` of the job log stream, from the first (JetStream replay).

    A message may carry several lines (``armnet_core.logbatch``); ``expected`` counts lines.
    """
    import asyncio

    import nats
    import nats.errors
    from armnet_core.logbatch import split_lines
    from nats.js.api import ConsumerConfig, DeliverPolicy

    assert url is not None

    async def read() -> list[str]:
        nc = await nats.connect(url)
        try:
            sub = await nc.jetstream().subscribe(
                subject, ordered_consumer=True, config=ConsumerConfig(deliver_policy=DeliverPolicy.ALL))
            got: list[str] = []
            while True:
                try:
                    msg = await sub.next_msg(timeout=10 if len(got) < expected else 1)
                except nats.errors.TimeoutError:
                    return got
                got.extend(line.decode() for _, line in split_lines(msg.data, msg.headers))
        finally:
            await nc.close()

    return asyncio.run(read())
