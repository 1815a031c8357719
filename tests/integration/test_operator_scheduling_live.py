"""The operator against the real kube-apiserver: binding, queueing, cancel, finalizer, TTL, offline.

The operator runs in-process (``kopf.testing.KopfRunner``); the test plays the
node agent's part by heartbeating Cells and patching RobotJob status exactly as
the agent does. Each test uses its own namespace and a unique embodiment so
cluster-scoped Cells from other tests never match its jobs.
"""

from __future__ import annotations

import collections
import contextlib
import json
import threading
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from armnet_core.api import (
    ACTIVE_PHASES,
    API_VERSION,
    CELLS,
    GROUP,
    RELEASE_CELL_FINALIZER,
    ROBOTJOBS,
    VERSION,
)
from armnet_core.times import kube_time, micro_time, parse_time
from kubernetes import watch

from tests.integration.operator_bed import Bed, running_operator

pytestmark = pytest.mark.integration


def test_a_job_binds_to_a_ready_cell_which_names_it(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")
    bed.job("pick")
    body = bed.wait_job("pick", phase="dispatched", cellName=cell)
    assert bed.get_cell(cell)["status"]["currentJob"] == f"{bed.ns}/pick"
    assert bed.condition(body, "Bound")["status"] == "True"
    assert body["status"]["jobId"] == body["metadata"]["uid"]
    # The finalizer is written after the bind, off the submit->bound path.
    bed.wait(
        "the finalizer",
        lambda: RELEASE_CELL_FINALIZER in (bed.get_job("pick") or {}).get("metadata", {}).get("finalizers", []),
    )
    bed.wait("a Bound event", lambda: "Bound" in bed.events("pick"))


def test_higher_priority_binds_first_and_the_rest_wait_with_a_position(bed: Bed, operator: Any) -> None:
    bed.job("low-1")
    bed.job("low-2")
    bed.job("urgent", priority=10)
    bed.wait_job("low-2", phase="queued", queuedReason="NoCellForEmbodiment")
    cell = bed.cell("c1")
    bed.wait_job("urgent", phase="dispatched", cellName=cell)
    assert bed.wait_job("low-1", phase="queued", queuedReason="AllCellsBusy")["status"]["queuePosition"] == 1
    assert bed.wait_job("low-2", queuePosition=2)["status"]["queuedReason"] == "AllCellsBusy"


def table_row(header: str, row: str) -> dict[str, str]:
    """A kubectl table's row by column name, cut at the header's column starts."""
    starts = [i for i, ch in enumerate(header) if ch != " " and (i == 0 or header[i - 1] == " ")]
    ends = [*starts[1:], None]
    return {header[a:b].strip(): row[a:b].strip() for a, b in zip(starts, ends, strict=True)}


def when(body: dict[str, Any], field: str) -> datetime:
    """The moment a job's status field names (it must name one)."""
    moment = parse_time(body["status"][field])
    assert moment is not None, body["status"]
    return moment


def bound_moment(bed: Bed, job: dict[str, Any]) -> datetime:
    """When the operator bound the job: its Bound condition's transition."""
    moment = parse_time(bed.condition(job, "Bound")["lastTransitionTime"])
    assert moment is not None, job["status"]
    return moment


def test_a_job_waiting_for_busy_cells_says_when_it_starts_at_the_latest(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")  # the CRD's default grace period: 10 s
    bed.job("running", timeoutSeconds=300)
    bound = bed.wait_job("running", phase="dispatched", cellName=cell)
    bed.job("first", timeoutSeconds=60)
    bed.job("second", timeoutSeconds=60)  # created in the same second: the name breaks the tie
    second = bed.wait("the second job's estimate", lambda: (
        (body := bed.get_job("second")) and body.get("status", {}).get("estimatedStart") and body))
    first = bed.get_job("first")
    bound_at = bound_moment(bed, bound)
    # Bound but not started: the running job holds the cell from its binding for its timeout and grace.
    assert abs((when(first, "estimatedStart") - bound_at).total_seconds() - (300 + 10)) <= 1
    assert (when(second, "estimatedStart") - when(first, "estimatedStart")).total_seconds() == 60 + 10
    # Bound: the estimate is gone.
    bed.agent_sets("running", "succeeded")
    assert bed.wait_job("first", phase="dispatched", cellName=cell)["status"].get("estimatedStart") is None


def test_a_job_waiting_behind_an_embodiment_with_finished_runs_says_when_it_likely_starts(
        bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")  # the CRD's default grace period: 10 s
    bed.job("ran", timeoutSeconds=300)
    bed.wait_job("ran", phase="dispatched", cellName=cell)
    # The agent's record of a finished run: 40 s from its start to its end.
    ended = datetime.now(UTC).replace(microsecond=0)
    bed.api.patch_namespaced_custom_object_status(GROUP, VERSION, bed.ns, ROBOTJOBS, "ran", {"status": {
        "phase": "succeeded", "startedAt": kube_time(ended - timedelta(seconds=40)), "finishedAt": kube_time(ended)}})
    bed.job("running", timeoutSeconds=300)
    bound = bed.wait_job("running", phase="dispatched", cellName=cell)
    bed.job("waiting", timeoutSeconds=60)
    waiting = bed.wait("the waiting job's estimates", lambda: (
        (body := bed.get_job("waiting")) and body.get("status", {}).get("likelyStart") and body))
    bound_at = bound_moment(bed, bound)
    # At the latest the running job uses its whole timeout and grace; likely, the embodiment's typical run.
    assert abs((when(waiting, "estimatedStart") - bound_at).total_seconds() - (300 + 10)) <= 1
    assert abs((when(waiting, "likelyStart") - bound_at).total_seconds() - 40) <= 1
    header, row = bed.k8s.kubectl("get", "rj", "waiting", "-n", bed.ns, "-o", "wide").stdout.splitlines()
    assert "LIKELY-START" in header.split() and waiting["status"]["likelyStart"] in row.split()
    # The cell's own summary for the cell operator: one job waits for it; its job likely ends, and at the latest.
    queue = bed.wait("the cell's queue summary", lambda: (
        (summary := bed.get_cell(cell).get("status", {}).get("queue") or {}).get("waitingJobs") == 1 and summary))
    assert abs((when({"status": queue}, "likelyFree") - bound_at).total_seconds() - 40) <= 1
    assert abs((when({"status": queue}, "latestFree") - bound_at).total_seconds() - (300 + 10)) <= 1
    header, row = bed.k8s.kubectl("get", "cell", cell, "-o", "wide").stdout.splitlines()
    columns = table_row(header, row)  # by position: kubectl leaves an empty column blank (no task here)
    assert (columns["WAITING"], columns["LIKELY-FREE"]) == ("1", queue["likelyFree"]), (header, row)


def test_queue_reasons_say_why_a_job_waits(bed: Bed, operator: Any) -> None:
    bed.cell("cordoned", task="fold", unschedulable=True)
    bed.job("no-embodiment", embodiment="test/nobody-has-this")
    bed.job("no-task", task="stack")
    bed.job("unavailable", task="fold")
    bed.wait_job("no-embodiment", phase="queued", queuedReason="NoCellForEmbodiment")
    body = bed.wait_job("no-task", phase="queued", queuedReason="NoCellForEmbodimentAndTask")
    assert "drop spec.task" in bed.condition(body, "Queued")["message"]
    bed.wait_job("unavailable", phase="queued", queuedReason="AllCellsUnavailable")


def test_cancelling_a_queued_job_ends_it_at_once(bed: Bed, operator: Any) -> None:
    bed.job("waits")
    bed.wait_job("waits", phase="queued")
    bed.k8s.kubectl("patch", "robotjob", "waits", "-n", bed.ns, "--type=merge", "-p", '{"spec":{"cancel":true}}')
    assert bed.wait_job("waits", phase="cancelled")["status"]["finishedAt"]


def test_cancelling_a_running_job_asks_the_agent_and_frees_the_cell_when_it_reports(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")
    bed.job("long")
    bed.wait_job("long", phase="dispatched")
    bed.agent_sets("long", "running")
    bed.k8s.kubectl("patch", "robotjob", "long", "-n", bed.ns, "--type=merge", "-p", '{"spec":{"cancel":true}}')
    bed.wait("CancelRequested", lambda: any(
        c["type"] == "CancelRequested" for c in (bed.get_job("long") or {}).get("status", {}).get("conditions", [])))
    assert bed.get_job("long")["status"]["phase"] == "running"
    bed.agent_sets("long", "cancelled")
    bed.wait("the cell released", lambda: not bed.get_cell(cell)["status"].get("currentJob"))


def test_deleting_a_running_job_waits_for_the_cell_to_be_released(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")
    bed.job("doomed")
    bed.wait_job("doomed", phase="dispatched")
    bed.agent_sets("doomed", "running")
    bed.k8s.kubectl("delete", "robotjob", "doomed", "-n", bed.ns, "--wait=false")
    bed.wait("CancelRequested on the deleted job", lambda: any(
        c["type"] == "CancelRequested" for c in (bed.get_job("doomed") or {}).get("status", {}).get("conditions", [])))
    assert bed.get_job("doomed")["metadata"]["deletionTimestamp"]
    bed.agent_sets("doomed", "cancelled")
    bed.wait("the job gone", lambda: bed.get_job("doomed") is None)
    assert not bed.get_cell(cell)["status"].get("currentJob")


def test_a_finished_job_frees_its_cell_for_the_next_and_is_deleted_after_its_ttl(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")
    bed.job("first", ttlSecondsAfterFinished=1)
    bed.job("second")
    bed.wait_job("first", phase="dispatched")
    bed.agent_sets("first", "running")
    bed.wait("a Started event", lambda: "Started" in bed.events("first"))
    bed.agent_sets("first", "succeeded", result={"exitCode": 0, "returnValue": {"score": 1}})
    bed.wait_job("second", phase="dispatched", cellName=cell)
    bed.wait("first deleted by its TTL", lambda: bed.get_job("first") is None)
    # Events go out from a background poster, in order: the Finished one may still be queued
    # behind the module's other Events when the TTL has already removed the job (a loaded CI run).
    bed.wait("its Bound, Started and Finished Events", lambda: {"Bound", "Started", "Finished"} <= set(bed.events("first")))


def test_finished_jobs_lose_their_finalizer_so_they_delete_at_once_after_the_operator_is_gone(
    k8s: Any, namespace: str, bed: Bed, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``helm uninstall`` keeps RobotJobs but removes the operator: a kept job must not hang ``kubectl delete``.

    ``kept`` finishes under the operator; ``legacy`` finished with the finalizer on
    before this operator started (as an older one left it): both lose it, level-based.
    """
    finalizer = RELEASE_CELL_FINALIZER

    def finalizers(name: str) -> list[str]:
        return list((bed.get_job(name) or {}).get("metadata", {}).get("finalizers") or [])

    bed.apply({"apiVersion": API_VERSION, "kind": "RobotJob",
               "metadata": {"name": "legacy", "namespace": bed.ns, "finalizers": [finalizer]},
               "spec": {"image": "localhost/armnet-test:dev", "embodiment": bed.embodiment}})
    bed.agent_sets("legacy", "succeeded")
    with running_operator(k8s, namespace, monkeypatch):
        cell = bed.cell("c1")
        bed.job("kept")
        bed.wait_job("kept", phase="dispatched", cellName=cell)
        bed.wait("the finalizer on the live job", lambda: finalizer in finalizers("kept"))
        bed.agent_sets("kept", "running")
        bed.agent_sets("kept", "succeeded")
        bed.wait("the cell released", lambda: not bed.get_cell(cell)["status"].get("currentJob"))
        bed.wait("the finished job's finalizer removed", lambda: not finalizers("kept"))
        bed.wait("the older finished job's finalizer removed", lambda: not finalizers("legacy"))
    assert bed.get_job("kept")["status"]["phase"] == "succeeded", "kept: only the finalizer went, not the job"
    done = bed.k8s.kubectl("delete", "robotjob", "kept", "legacy", "-n", bed.ns, "--timeout=30s", check=False)
    assert done.returncode == 0, done.stderr
    assert bed.get_job("kept") is None and bed.get_job("legacy") is None


def test_a_job_dispatched_to_a_cell_that_goes_offline_is_requeued_to_another(bed: Bed, operator: Any) -> None:
    flaky = bed.cell("a-flaky")
    body = bed.wait_job(bed.job("j"), phase="dispatched", cellName=flaky)
    bed.alive.discard(flaky)
    spare = bed.cell("b-spare")
    body = bed.wait_job("j", phase="dispatched", cellName=spare)
    # Events go out from a background poster: the rebind may be visible before the Event is.
    bed.wait("a Requeued event", lambda: "Requeued" in bed.events("j"))
    bed.wait("the requeue counted", lambda: operator.metrics.requeues._value.get() == 1)
    bed.wait("the offline cell marked Offline and released", lambda: (
        bed.get_cell(flaky)["status"].get("phase") == "Offline" and not bed.get_cell(flaky)["status"].get("currentJob")))
    assert body["status"]["cellName"] == spare


def test_a_running_job_on_a_lost_cell_fails_with_the_reason(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")
    bed.job("j")
    bed.wait_job("j", phase="dispatched")
    bed.agent_sets("j", "running")
    bed.alive.discard(cell)
    body = bed.wait_job("j", phase="failed")
    assert body["status"]["result"]["error"] == f"cell {cell} lost"


def test_two_replicas_bind_50_jobs_over_5_cells_without_a_double_binding(
    k8s: Any, namespace: str, bed: Bed, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Both replicas write at once; watch streams see every state each object goes through.

    A job's own record is the binding: while it is active its cellName never changes, and
    no two active jobs ever name one cell. (A replica whose job write loses the race gives
    its provisional cell claim back at once; the agent ignores a claim the job does not
    confirm, so that transient is not a binding.)
    """
    violations: list[str] = []
    seen_jobs: dict[str, dict[str, Any]] = {}
    bound_to: dict[str, str] = {}
    seen_claims: dict[str, str] = {}
    latest: dict[str, tuple[dict[str, Any], str]] = {}
    stop = threading.Event()

    def watching(target: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                target()
            except Exception as error:  # noqa: BLE001 - a broken watch must fail the test
                if not stop.is_set():
                    violations.append(f"watch broke, states were missed: {error!r}")
        return run

    def every_event(list_call: Callable[..., Any], *args: Any) -> Iterator[dict[str, Any]]:
        """Each object a watch reports until the test stops, the watch re-opened from its last
        resourceVersion whenever the server ends it (a loaded run outlasts one watch's timeout:
        a watch that just ended left the simulated agent below blind and the jobs stuck)."""
        w = watch.Watch()
        version: str | None = None
        while not stop.is_set():
            since = {"resource_version": version} if version else {}
            for event in w.stream(list_call, *args, timeout_seconds=60, **since):
                if stop.is_set():
                    w.stop()
                    return
                yield event["object"]
            version = w.resource_version

    def watch_jobs() -> None:
        for obj in every_event(bed.api.list_namespaced_custom_object, GROUP, VERSION, bed.ns, ROBOTJOBS):
            name, status = obj["metadata"]["name"], obj.get("status", {})
            seen_jobs[name] = status
            latest[name] = (status, obj["metadata"]["resourceVersion"])  # one assignment: never torn
            active = [s["cellName"] for s in seen_jobs.values()
                      if s.get("phase") in ACTIVE_PHASES and s.get("cellName")]
            if len(active) != len(set(active)):
                violations.append(f"two active jobs on one cell: {sorted(active)}")
            # A phase without a cell is no binding (kept as a check: the simulated agent writes with
            # the version it saw, as the real one does, so it cannot land on a job just requeued).
            if status.get("phase") in ACTIVE_PHASES and status.get("cellName"):
                if bound_to.setdefault(name, status["cellName"]) != status["cellName"]:
                    violations.append(f"{name} moved from {bound_to[name]} to {status['cellName']} while active")
            elif status.get("phase") == "queued":
                bound_to.pop(name, None)

    def watch_cells() -> None:
        for obj in every_event(bed.api.list_cluster_custom_object, GROUP, VERSION, CELLS):
            if obj["metadata"]["name"] in bed.cells:
                seen_claims[obj["metadata"]["name"]] = obj.get("status", {}).get("currentJob") or ""

    def agent() -> None:
        """Start each dispatched job, finish each running one: the cells turn over fast.

        Each write carries the resourceVersion it was decided on, as the node agent's do: without
        it, a "running" decided on a dispatched job landed on the same job just requeued (a late
        heartbeat on a loaded machine), which then ran without a second binding."""
        while not stop.wait(0.2):
            for name, (status, version) in list(latest.items()):
                with contextlib.suppress(Exception):
                    if status.get("phase") == "dispatched":
                        bed.agent_sets(name, "running", precondition=version)
                    elif status.get("phase") == "running":
                        bed.agent_sets(name, "succeeded", precondition=version)

    cells = [bed.cell(f"c{i}") for i in range(5)]
    threads = [threading.Thread(target=t, daemon=True) for t in (watching(watch_jobs), watching(watch_cells), agent)]
    for t in threads:
        t.start()
    # Separate Lease names: both replicas believe they lead, so both bind concurrently and
    # only the resourceVersion preconditions keep them apart (the worst case on purpose).
    with running_operator(k8s, namespace, monkeypatch, lease_name="replica-a") as a, \
            running_operator(k8s, namespace, monkeypatch, lease_name="replica-b") as b:
        docs = [{"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": f"j{i:02d}", "namespace": bed.ns},
                 "spec": {"image": "localhost/armnet-test:dev", "embodiment": bed.embodiment}} for i in range(50)]
        bed.k8s.kubectl("apply", "-f", "-", input="\n---\n".join(json.dumps(d) for d in docs))
        def all_succeeded() -> bool:
            assert violations == [], violations  # a broken watch leaves the simulated agent blind: say so now
            return sum(1 for s in seen_jobs.values() if s.get("phase") == "succeeded") == 50

        try:
            bed.wait("all 50 jobs succeeded", all_succeeded, timeout=180)
        except AssertionError as error:
            census = collections.Counter(str(s.get("phase")) for s in seen_jobs.values())
            failed = {n: (s.get("result") or {}).get("error") for n, s in seen_jobs.items() if s.get("phase") == "failed"}
            raise AssertionError(f"{error}\njobs by phase as watched: {dict(census)}; failed: {failed}; "
                                 f"cell claims: {seen_claims}; "
                                 f"binds {[r.metrics.binds._value.get() for r in (a, b)]}") from None
        bed.wait("every cell released", lambda: not any(seen_claims.values()))
    stop.set()
    binds = [r.metrics.binds._value.get() for r in (a, b)]
    conflicts = [r.metrics.conflicts._value.get() for r in (a, b)]
    requeues = [r.metrics.requeues._value.get() for r in (a, b)]
    print(f"binds per replica {binds}, conflicts {conflicts}, requeues {requeues}")
    assert violations == []
    # A requeue (e.g. a heartbeat late by more than the 3 s timeout on a loaded machine)
    # legitimately binds that job once more; anything beyond that would be a double bind.
    assert sum(binds) == 50 + sum(requeues), "every job is bound once per time it was queued"
    assert sum(requeues) <= 10, f"requeues {requeues}: the repair is undoing good bindings"
    assert {s.get("cellName") for s in seen_jobs.values()} <= set(cells)


def test_with_a_shared_lease_only_the_leader_binds(
    k8s: Any, namespace: str, bed: Bed, monkeypatch: pytest.MonkeyPatch
) -> None:
    cells = [bed.cell(f"c{i}") for i in range(3)]
    # A lease long enough that a pass slowed by a loaded machine cannot hand leadership over mid-test.
    lease = {"lease_duration": 15}
    with running_operator(k8s, namespace, monkeypatch, **lease) as a, running_operator(
        k8s, namespace, monkeypatch, **lease
    ) as b:
        for i in range(3):
            bed.job(f"j{i}")
        for i in range(3):
            assert bed.wait_job(f"j{i}", phase="dispatched")["status"]["cellName"] in cells
        # The metrics are updated when the pass ends, a moment after its writes are visible. At
        # least 3: on a loaded host a pass can meet its own claim before the job's write shows
        # in its cache, release the cell and bind again (seen at load 14: "claim ... was never
        # completed"); what this test specifies is that the follower binds nothing.
        leader = bed.wait("the leader counted its 3 binds", lambda: next(
            (r for r in (a, b) if r.leading and r.metrics.binds._value.get() >= 3), None))
        follower = b if leader is a else a
        assert not follower.leading
        assert follower.metrics.binds._value.get() == 0


def test_the_finalizer_json_patch_keeps_other_finalizers_and_refuses_a_stale_absent_list(bed: Bed) -> None:
    """Against the real server: append keeps others; a list that appeared since the read is a Conflict."""
    from armnet_operator.errors import Conflict
    from armnet_operator.kube import KubeApi, make_client
    from armnet_operator.parsing import parse_job
    from armnet_operator.patches import add_finalizer

    api = KubeApi(make_client(str(bed.k8s.kubeconfig)), "armnet-test", "test")
    try:
        bed.job("bare")
        bare = parse_job(bed.wait("the job", lambda: bed.get_job("bare")))
        written = api.patch(add_finalizer(bare))
        assert written["metadata"]["finalizers"] == [RELEASE_CELL_FINALIZER]

        bed.job("stale")
        stale = parse_job(bed.wait("the job", lambda: bed.get_job("stale")))
        bed.api.patch_namespaced_custom_object(
            GROUP, VERSION, bed.ns, ROBOTJOBS, "stale", {"metadata": {"finalizers": ["other.io/keep"]}}
        )
        with pytest.raises(Conflict):
            api.patch(add_finalizer(stale))  # the test op sees the list that appeared
        fresh = parse_job(api.read_job(bed.ns, "stale"))
        written = api.patch(add_finalizer(fresh))
        assert written["metadata"]["finalizers"] == ["other.io/keep", RELEASE_CELL_FINALIZER]
        with pytest.raises(Conflict):
            api.patch(add_finalizer(fresh))  # the list is no longer as seen: never a duplicate

        bed.job("raced")
        raced = parse_job(bed.wait("the job", lambda: bed.get_job("raced")))
        bed.agent_sets("raced", "succeeded")  # the agent writes after our read
        written = api.patch(add_finalizer(raced))  # no resourceVersion: no conflict
        assert (written["metadata"]["finalizers"], written["status"]["phase"]) == ([RELEASE_CELL_FINALIZER], "succeeded")
    finally:
        for name in ("bare", "stale", "raced"):
            with contextlib.suppress(Exception):
                bed.api.patch_namespaced_custom_object(GROUP, VERSION, bed.ns, ROBOTJOBS, name, {"metadata": {"finalizers": None}})


def test_closing_the_api_posts_the_queued_events_joins_the_poster_and_sends_nothing_more(bed: Bed) -> None:
    """``KubeApi.close``: no thread of ours may be inside a request when the process exits (it aborted, -6)."""
    from armnet_operator.errors import TransientError
    from armnet_operator.kube import KubeApi, make_client
    from armnet_operator.parsing import parse_job

    api = KubeApi(make_client(str(bed.k8s.kubeconfig)), "armnet-test", "test")
    bed.job("told")
    job = parse_job(bed.wait("the job", lambda: bed.get_job("told")))
    api.writing(True)  # a pass is writing: Events wait for it...
    for i in range(30):
        api.post_event(job, "Normal", f"Queued{i}", "queued before the stop")
    api.close()  # ...but not past the stop: they go out now, for EVENT_FLUSH_SECONDS, then the poster ends
    assert not api._poster.is_alive()
    # Each queued Event was posted or counted as dropped, in queue order: the flush window ends a
    # prefix (at load 14 it posted 22 of the 30 in its 3 s; on a quiet host all of them).
    queued = [f"Queued{i}" for i in range(30)]
    posted = set(queued) & set(bed.events("told"))
    assert posted and posted == set(queued[: len(posted)]), sorted(posted)
    assert len(posted) + api._dropped == len(queued)
    api.post_event(job, "Normal", "TooLate", "after the stop")  # dropped, never sent
    with pytest.raises(TransientError):
        api.read_job(bed.ns, "told")
    assert "TooLate" not in bed.events("told")


@pytest.mark.parametrize("skew_hours", [10, -10], ids=["holder-clock-ahead", "holder-clock-behind"])
def test_a_lease_held_by_a_replica_with_a_skewed_clock_expires_on_our_own_clock(bed: Bed, skew_hours: int) -> None:
    """Against the real server: the holder's renewTime is hours off our clock. While it renews, it keeps
    the Lease however far its clock is; once it stops, we take over after leaseDurationSeconds of our own
    (stepped by hand, so nothing here waits on the machine's speed)."""
    from armnet_operator.kube import KubeApi, make_client
    from kubernetes import client

    leases = client.CoordinationV1Api(bed.k8s.api_client())
    theirs = datetime.now(UTC) + timedelta(hours=skew_hours)

    def holder_writes(at: datetime, create: bool = False) -> None:
        spec = {"holderIdentity": "other", "renewTime": micro_time(at), "leaseDurationSeconds": 15}
        if create:
            leases.create_namespaced_lease(bed.ns, client.V1Lease.from_dict(  # type: ignore[no-untyped-call]
                {"metadata": {"name": "skewed", "namespace": bed.ns},
                 "spec": {**spec, "acquireTime": spec["renewTime"], "leaseTransitions": 2}}))
        else:
            leases.patch_namespaced_lease("skewed", bed.ns, {"spec": spec})

    ticks = [1000.0]
    api = KubeApi(make_client(str(bed.k8s.kubeconfig)), "armnet-test", "me", monotonic=lambda: ticks[0])
    try:
        holder_writes(theirs, create=True)
        for beat in range(1, 6):  # 5 renewals 10 s apart on our clock: 50 s, over three lease durations
            assert not api.hold_lease(bed.ns, "skewed", timedelta(seconds=15), datetime.now(UTC))
            ticks[0] += 10
            holder_writes(theirs + timedelta(seconds=10 * beat))
        assert not api.hold_lease(bed.ns, "skewed", timedelta(seconds=15), datetime.now(UTC))  # sees the last renewal
        ticks[0] += 15
        assert not api.hold_lease(bed.ns, "skewed", timedelta(seconds=15), datetime.now(UTC))  # exactly 15 s: not yet
        assert leases.read_namespaced_lease("skewed", bed.ns).spec.holder_identity == "other"
        ticks[0] += 0.5
        assert api.hold_lease(bed.ns, "skewed", timedelta(seconds=15), datetime.now(UTC))
        spec = leases.read_namespaced_lease("skewed", bed.ns).spec
        assert (spec.holder_identity, spec.lease_transitions) == ("me", 3)
        ticks[0] += 3600  # our own lease renews whatever our clock did
        assert api.hold_lease(bed.ns, "skewed", timedelta(seconds=15), datetime.now(UTC))
    finally:
        api.close()
