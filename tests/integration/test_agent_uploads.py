"""The node agent's upload queue: a real API server, a real S3 store (SeaweedFS), no runner.

What must hold whatever happens to the agent: an ended job's output reaches the store
once, the job's ``status.artifacts`` says where, and the directory leaves the robot host
only after that. The queue is driven the way the agent drives it (``track`` at launch,
``ready`` after the terminal status, ``run`` in a thread) or, for a crash, by a second
queue on the same state directory that never heard of the job.
"""

from __future__ import annotations

import json
import logging
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from armnet_client import Client
from armnet_core.resources import JobArtifacts
from armnet_node.artifacts import ObjectStore, OutputLimits, StoreConfig
from armnet_node.kube import AgentKube
from armnet_node.metrics import AgentMetrics
from armnet_node.plan import HostPaths
from armnet_node.uploads import TrackedJob, UploadQueue
from armnet_testbed.objstore import SeaweedS3
from armnet_testbed.procs import free_port, wait_until

from tests.support.fms_objects import a_job, apply, get, patch_status

pytestmark = pytest.mark.integration


@pytest.fixture
def bucket_store(object_store: SeaweedS3) -> ObjectStore:
    store = ObjectStore(StoreConfig(bucket=f"up-{uuid.uuid4().hex[:12]}", access_key_id=object_store.access_key,
                                    secret_access_key=object_store.secret_key, endpoint_url=object_store.endpoint))
    store.ensure_bucket()
    return store


@pytest.fixture
def kube(k8s: Any) -> AgentKube:
    return AgentKube(k8s.api_client())


def a_tracked_job(k8s: Any, namespace: str, phase: str | None = None) -> TrackedJob:
    created = apply(k8s, a_job(f"out-{uuid.uuid4().hex[:6]}", namespace))
    meta = created["metadata"]
    if phase is not None:
        patch_status(k8s, "job", meta["name"], {"phase": phase}, namespace)
    return TrackedJob(namespace, meta["name"], meta["uid"])


def write_output(paths: HostPaths, job: TrackedJob, files: dict[str, bytes]) -> Path:
    out = paths.output_dir(job.uid)
    for name, data in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(data)
    return out


def artifacts_of(k8s: Any, job: TrackedJob) -> dict[str, Any]:
    return dict((get(k8s, "job", job.name, job.namespace).get("status") or {}).get("artifacts") or {})


@pytest.fixture
def running_queue() -> Iterator[list[threading.Event]]:
    """Stop events of the queues a test started; each is stopped after it."""
    stops: list[threading.Event] = []
    yield stops
    for stop in stops:
        stop.set()


def start(queue: UploadQueue, stops: list[threading.Event]) -> None:
    stop = threading.Event()
    stops.append(stop)
    threading.Thread(target=queue.run, args=(stop,), daemon=True).start()


def test_an_ended_job_s_output_is_stored_and_its_status_says_where(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3,
    tmp_path: Path, running_queue: list[threading.Event],
) -> None:
    paths = HostPaths(tmp_path)
    metrics = AgentMetrics()
    queue = UploadQueue(bucket_store, paths, kube, metrics)
    job = a_tracked_job(k8s, namespace)
    queue.track(job)
    out = write_output(paths, job, {"data/episode_000.parquet": b"p" * 5000, "meta/info.json": b'{"fps": 30}'})
    (out / "escape").symlink_to("/etc/hostname")
    start(queue, running_queue)
    patch_status(k8s, "job", job.name, {"phase": "succeeded"}, namespace)
    queue.ready(job.uid)

    wait_until(lambda: not out.exists(), timeout=60, what="the output directory removed after its upload")
    artifacts = artifacts_of(k8s, job)
    prefix = f"{namespace}/{job.uid}/"
    assert artifacts["phase"] == "Uploaded", artifacts
    assert artifacts["location"] == f"s3://{bucket_store.bucket}/{prefix}"
    assert (artifacts["files"], artifacts["bytes"], artifacts["complete"], artifacts["leftOut"]) == (2, 5011, True, 1)
    assert "escape: a symbolic link that leads out of the output directory" in artifacts["message"]
    objects = object_store.objects(bucket_store.bucket, prefix)
    assert objects[prefix + "files/data/episode_000.parquet"] == b"p" * 5000
    assert json.loads(objects[prefix + "manifest.json"])["complete"] is True
    assert not (paths.state_dir / "uploads" / f"{job.uid}.json").exists()
    assert metrics.outputs.labels(outcome="uploaded")._value.get() == 1
    assert metrics.output_bytes._value.get() == 5011


def test_the_cells_record_is_stored_beside_the_output_and_a_forged_one_is_left_out(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3, tmp_path: Path,
) -> None:
    paths = HostPaths(tmp_path)
    queue = UploadQueue(bucket_store, paths, kube, AgentMetrics())
    job = a_tracked_job(k8s, namespace, "succeeded")
    queue.track(job)
    write_output(paths, job, {"data.parquet": b"d" * 100, "armnet-cell/rollouts.json": b'{"forged": true}'})
    record = paths.record_dir(job.uid)
    (record / "rollouts" / "000001-t").mkdir(parents=True)
    (record / "rollouts" / "000001-t" / "first.jpg").write_bytes(b"\xff\xd8\xff picture")
    (record / "rollouts.json").write_bytes(b'{"rollouts": []}')
    queue.ready(job.uid)
    queue.process_ready()

    prefix = f"{namespace}/{job.uid}/files/"
    stored = object_store.objects(bucket_store.bucket, prefix)
    assert stored == {prefix + "data.parquet": b"d" * 100,
                      prefix + "armnet-cell/rollouts.json": b'{"rollouts": []}',
                      prefix + "armnet-cell/rollouts/000001-t/first.jpg": b"\xff\xd8\xff picture"}
    artifacts = artifacts_of(k8s, job)
    assert (artifacts["files"], artifacts["leftOut"]) == (3, 1)
    assert "armnet-cell: a name reserved for the cell's record" in artifacts["message"]
    assert not record.exists() and not paths.output_dir(job.uid).exists()


def test_an_agent_killed_before_the_upload_leaves_it_to_the_next_agent(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3,
    tmp_path: Path, running_queue: list[threading.Event],
) -> None:
    paths = HostPaths(tmp_path)
    first = UploadQueue(bucket_store, paths, kube, AgentMetrics())
    ended, deleted, running = (a_tracked_job(k8s, namespace, phase) for phase in ("failed", "succeeded", "running"))
    for job in (ended, deleted, running):
        first.track(job)
        write_output(paths, job, {"result.txt": job.name.encode()})
    k8s.kubectl("delete", "robotjob", deleted.name, "-n", namespace)
    # The first agent dies here: nobody called ready(). The next one only has the state directory.
    start(UploadQueue(bucket_store, paths, kube, AgentMetrics()), running_queue)

    for job in (ended, deleted):
        wait_until(lambda job=job: not paths.output_dir(job.uid).exists(), timeout=60,  # type: ignore[misc]
                   what=f"{job.name}'s output uploaded by the next agent")
        key = f"{namespace}/{job.uid}/files/result.txt"
        assert object_store.objects(bucket_store.bucket, key) == {key: job.name.encode()}
    assert artifacts_of(k8s, ended)["phase"] == "Uploaded"
    # A job still running keeps its directory: its output is not final.
    assert paths.output_dir(running.uid).exists()
    assert (paths.state_dir / "uploads" / f"{running.uid}.json").exists()


#: The agent killed mid-upload: ``upload_output`` in a process of its own that stops after its
#: ``HOLD_AFTER``-th stored file until it is SIGKILLed (so the kill lands mid-upload however slowly
#: the host runs), its store from the env.
KILLED_UPLOADER = """
import os, sys, threading
from pathlib import Path
from armnet_node.artifacts import ObjectStore, StoreConfig
from armnet_node.artifacts.scan import scan_output
from armnet_node.artifacts.model import OutputLimits
from armnet_core.output_keys import job_prefix
from armnet_node.artifacts.upload import upload_scan

root, namespace, uid, hold_after = Path(sys.argv[1]), sys.argv[2], sys.argv[3], int(sys.argv[4])
store = ObjectStore(StoreConfig.from_env())
stored = []

def on_stored(artifact):
    stored.append(artifact.path)
    print(f"stored {artifact.path}", flush=True)
    if len(stored) == hold_after:
        threading.Event().wait()  # until the test kills this process

upload_scan(scan_output(root, OutputLimits(), job_prefix(namespace, uid)), store, namespace, uid, on_stored)
print("finished", flush=True)
"""


def test_an_agent_killed_mid_upload_is_resumed_by_the_next_one_and_nothing_is_sent_twice(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3,
    tmp_path: Path, running_queue: list[threading.Event],
) -> None:
    import os
    import signal
    import subprocess
    import sys

    paths = HostPaths(tmp_path)
    job = a_tracked_job(k8s, namespace, "succeeded")
    UploadQueue(bucket_store, paths, kube, AgentMetrics()).track(job)
    files = {f"data/chunk-{i:03d}.parquet": os.urandom(64 << 10) for i in range(40)}
    out = write_output(paths, job, files)
    env = {**os.environ, **object_store.agent_env(bucket_store.bucket)}
    uploader = subprocess.Popen([sys.executable, "-c", KILLED_UPLOADER, str(out), namespace, job.uid, "15"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    assert uploader.stdout is not None
    first = [uploader.stdout.readline().split(" ", 1)[1].strip() for _ in range(15)]
    uploader.send_signal(signal.SIGKILL)
    assert uploader.wait(30) == -signal.SIGKILL, uploader.stderr.read() if uploader.stderr else ""
    prefix = f"{namespace}/{job.uid}/"
    client = object_store.client()

    def stored() -> dict[str, Any]:
        listed = client.list_objects_v2(Bucket=bucket_store.bucket, Prefix=prefix).get("Contents", [])
        return {item["Key"]: item["LastModified"] for item in listed}

    before = stored()
    assert set(before) == {f"{prefix}files/{path}" for path in first}  # mid-upload: no manifest yet

    metrics = AgentMetrics()
    start(UploadQueue(bucket_store, paths, kube, metrics), running_queue)  # the next agent
    wait_until(lambda: not out.exists(), timeout=90, what="the next agent's upload of the rest")

    after = stored()
    assert set(after) == {f"{prefix}files/{path}" for path in files} | {f"{prefix}manifest.json"}
    assert {key: after[key] for key in before} == before
    # The 15 stored before the kill were not sent again: the next agent sent the other 25 only.
    assert metrics.output_bytes._value.get() == 25 * (64 << 10)
    objects = object_store.objects(bucket_store.bucket, prefix)
    assert all(objects[f"{prefix}files/{path}"] == data for path, data in files.items())
    manifest = json.loads(objects[f"{prefix}manifest.json"])
    assert manifest["complete"] is True and len(manifest["files"]) == len(files)
    assert artifacts_of(k8s, job)["phase"] == "Uploaded"


def test_a_store_that_does_not_answer_keeps_the_output_and_the_next_agent_stores_it(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3,
    tmp_path: Path, running_queue: list[threading.Event],
) -> None:
    paths = HostPaths(tmp_path)
    metrics = AgentMetrics()
    nothing_there = ObjectStore(StoreConfig(
        bucket=bucket_store.bucket, access_key_id=object_store.access_key, secret_access_key=object_store.secret_key,
        endpoint_url=f"http://127.0.0.1:{free_port()}"), max_attempts=1)
    queue = UploadQueue(nothing_there, paths, kube, metrics)
    job = a_tracked_job(k8s, namespace, "succeeded")
    queue.track(job)
    out = write_output(paths, job, {"a.bin": b"kept"})
    queue.ready(job.uid)
    queue.process_ready()

    artifacts = artifacts_of(k8s, job)
    assert artifacts["phase"] == "Retrying", artifacts
    assert "the output is kept on the robot host and the upload is retried" in artifacts["message"]
    assert out.exists()
    assert metrics.output_upload_failures.labels(reason="unavailable")._value.get() == 1
    assert metrics.outputs_pending._value.get() == 1

    start(UploadQueue(bucket_store, paths, kube, AgentMetrics()), running_queue)  # restarted with the store back
    wait_until(lambda: not out.exists(), timeout=60, what="the kept output uploaded")
    assert artifacts_of(k8s, job)["phase"] == "Uploaded"


def test_an_output_over_the_cap_is_not_stored_and_the_job_is_told_why(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3,
    tmp_path: Path,
) -> None:
    paths = HostPaths(tmp_path)
    metrics = AgentMetrics()
    queue = UploadQueue(bucket_store, paths, kube, metrics, OutputLimits(max_files=10))
    job = a_tracked_job(k8s, namespace, "succeeded")
    queue.track(job)
    write_output(paths, job, {f"f{i}": b"x" for i in range(50)})
    queue.ready(job.uid)
    queue.process_ready()

    artifacts = artifacts_of(k8s, job)
    assert artifacts["phase"] == "Failed"
    assert "more than 10 entries" in artifacts["message"] and "nothing was stored" in artifacts["message"]
    assert not paths.output_dir(job.uid).exists()
    assert object_store.objects(bucket_store.bucket, f"{namespace}/{job.uid}/") == {}
    assert metrics.outputs.labels(outcome="too_large")._value.get() == 1


def test_an_output_over_the_cap_does_not_take_the_cells_record_with_it(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3,
    tmp_path: Path,
) -> None:
    """A job must not erase the pictures of its own evaluation by writing too much."""
    paths = HostPaths(tmp_path)
    queue = UploadQueue(bucket_store, paths, kube, AgentMetrics(), OutputLimits(max_files=10))
    job = a_tracked_job(k8s, namespace, "succeeded")
    queue.track(job)
    write_output(paths, job, {f"f{i}": b"x" for i in range(50)})
    paths.record_dir(job.uid).mkdir(parents=True)
    (paths.record_dir(job.uid) / "rollouts.json").write_bytes(b'{"rollouts": []}')
    queue.ready(job.uid)
    queue.process_ready()

    artifacts = artifacts_of(k8s, job)
    assert artifacts["phase"] == "Failed" and "only the cell's record was stored" in artifacts["message"]
    prefix = f"{namespace}/{job.uid}/"
    assert artifacts["location"] == f"s3://{bucket_store.bucket}/{prefix}"  # the operator removes it at the TTL
    stored = object_store.objects(bucket_store.bucket, prefix)
    assert sorted(stored) == [prefix + "files/armnet-cell/rollouts.json", prefix + "manifest.json"]
    assert not paths.output_dir(job.uid).exists() and not paths.record_dir(job.uid).exists()


def test_without_a_store_the_output_is_removed_and_a_job_that_wrote_something_is_told(
    k8s: Any, namespace: str, kube: AgentKube, tmp_path: Path,
) -> None:
    paths = HostPaths(tmp_path)
    queue = UploadQueue(None, paths, kube, AgentMetrics())
    wrote, silent = a_tracked_job(k8s, namespace, "succeeded"), a_tracked_job(k8s, namespace, "succeeded")
    for job in (wrote, silent):
        queue.track(job)
        paths.output_dir(job.uid).mkdir(parents=True)
        queue.ready(job.uid)
    write_output(paths, wrote, {"episode.parquet": b"lost"})
    # The terminal status says Pending only where a final phase will follow (Discarded).
    assert (queue.pending_status(wrote.uid), queue.pending_status(silent.uid)) == ({"phase": "Pending"}, None)
    queue.process_ready()

    assert not paths.output_dir(wrote.uid).exists() and not paths.output_dir(silent.uid).exists()
    artifacts = artifacts_of(k8s, wrote)
    assert artifacts["phase"] == "Discarded"
    assert "artifacts.bucket" in artifacts["message"]
    assert artifacts_of(k8s, silent) == {}
    assert queue.tracked() == []


def test_a_client_waiting_for_a_result_marked_pending_gets_where_the_output_was_stored(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, tmp_path: Path,
) -> None:
    """``wait``/``execute`` return ``result.artifacts`` once the upload the terminal status announced settled."""
    paths = HostPaths(tmp_path)
    queue = UploadQueue(bucket_store, paths, kube, AgentMetrics())
    job = a_tracked_job(k8s, namespace)
    assert queue.pending_status(job.uid) is None  # not tracked: no upload will follow
    queue.track(job)
    write_output(paths, job, {"data/episode_000.parquet": b"p" * 5000})
    # The runner writes the terminal status with the queue's word: a final phase will follow.
    patch_status(k8s, "job", job.name, {"phase": "succeeded", "artifacts": queue.pending_status(job.uid)}, namespace)
    client = Client(kubeconfig=str(k8s.kubeconfig), namespace=namespace, env={}, poll_interval_s=0.1)

    # Not waited for where only the exit status matters (`armnet submit`), nor past artifacts_wait_s.
    assert client.wait_terminal(job.name, None, stored_output=False)[1].artifacts == JobArtifacts(phase="Pending")
    client.artifacts_wait_s = 0.3
    assert client.wait(job.name).artifacts == JobArtifacts(phase="Pending")

    # The upload is let go only once the client says it waits for it.
    client.artifacts_wait_s = 120.0
    waiting = threading.Event()
    said = logging.Handler()
    said.emit = lambda record: waiting.set() if "waiting for the node agent" in record.getMessage() else None  # type: ignore[method-assign]
    client_log = logging.getLogger("armnet_client")
    level = client_log.level
    client_log.setLevel(logging.INFO)
    client_log.addHandler(said)
    uploader = threading.Thread(target=lambda: waiting.wait(60) and (queue.ready(job.uid), queue.process_ready()))
    uploader.start()
    try:
        result = client.wait(job.name)
    finally:
        waiting.set()
        uploader.join()
        client_log.removeHandler(said)
        client_log.setLevel(level)
    assert result.artifacts is not None and result.artifacts.phase == "Uploaded", result.artifacts
    assert result.artifacts.location == f"s3://{bucket_store.bucket}/{namespace}/{job.uid}/"
    assert (result.artifacts.files, result.artifacts.bytes, result.artifacts.complete) == (1, 5000, True)


def test_a_job_its_runner_still_runs_is_not_taken_even_deleted(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3, tmp_path: Path,
) -> None:
    paths = HostPaths(tmp_path)
    queue = UploadQueue(bucket_store, paths, kube, AgentMetrics())
    job = a_tracked_job(k8s, namespace)
    queue.track(job)  # the runner's: the container may still write in its grace window
    out = write_output(paths, job, {"partial.bin": b"half"})
    k8s.kubectl("delete", "robotjob", job.name, "-n", namespace)
    queue._sweep()
    queue.process_ready()
    assert out.exists() and object_store.objects(bucket_store.bucket, f"{namespace}/{job.uid}/") == {}

    queue.released(job.uid)  # the runner let go without a status: the next sweep decides
    queue._sweep()
    queue.process_ready()
    assert not out.exists()
    assert f"{namespace}/{job.uid}/files/partial.bin" in object_store.objects(bucket_store.bucket, f"{namespace}/")


def test_a_job_re_created_under_the_same_name_never_gets_the_old_job_s_status(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, tmp_path: Path,
) -> None:
    paths = HostPaths(tmp_path)
    metrics = AgentMetrics()
    queue = UploadQueue(bucket_store, paths, kube, metrics)
    old = a_tracked_job(k8s, namespace, "succeeded")
    queue.track(old)
    write_output(paths, old, {"a.txt": b"old job"})
    k8s.kubectl("delete", "robotjob", old.name, "-n", namespace)
    apply(k8s, a_job(old.name, namespace))  # the same name, another uid
    queue.ready(old.uid)
    queue.process_ready()

    assert artifacts_of(k8s, old) == {}  # `old` names the new job now
    assert not paths.output_dir(old.uid).exists()  # the old job's output is stored all the same
    assert metrics.outputs.labels(outcome="uploaded")._value.get() == 1
    assert metrics.outputs_pending._value.get() == 0


def test_a_later_phase_replaces_every_field_of_the_earlier_one(
    k8s: Any, namespace: str, kube: AgentKube, bucket_store: ObjectStore, object_store: SeaweedS3, tmp_path: Path,
) -> None:
    paths = HostPaths(tmp_path)
    job = a_tracked_job(k8s, namespace, "succeeded")
    nothing_there = ObjectStore(StoreConfig(
        bucket=bucket_store.bucket, access_key_id=object_store.access_key, secret_access_key=object_store.secret_key,
        endpoint_url=f"http://127.0.0.1:{free_port()}"), max_attempts=1)
    first = UploadQueue(nothing_there, paths, kube, AgentMetrics())
    first.track(job)
    write_output(paths, job, {"a.txt": b"x"})
    first.ready(job.uid)
    first.process_ready()
    assert "message" in artifacts_of(k8s, job)  # Retrying, with the store's error

    second = UploadQueue(bucket_store, paths, kube, AgentMetrics())
    second.ready(job.uid)
    second.process_ready()
    artifacts = artifacts_of(k8s, job)
    assert artifacts["phase"] == "Uploaded" and "message" not in artifacts  # nothing left out, no stale message
