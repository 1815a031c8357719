"""The client against the real operator: queue reason and position, cell phases, cancel of a queued job.

The operator runs in-process as in its own live tests; the Cell's heartbeat is
written the way the agent writes it (no agent exists yet). The job states shown
here are the operator's own decisions, never written by the test; the log lines
of the cancelled job are published as the agent would, to check that ``wait``
returns the whole output from the stream rather than the status tails.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import pytest
from armnet_core.models import JobSpec, JobStatus, RemoteExecutionError

from tests.integration.client_bed import Publisher, Tenant, stdout_lines
from tests.integration.operator_bed import Bed, running_operator

pytestmark = pytest.mark.integration


def eventually(what: str, check: Callable[[], Any], timeout: float = 30) -> Any:
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        last = check()
        if last:
            return last
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}; last: {last!r}")


def test_get_cells_and_cancel_show_the_operators_decisions(
    k8s: Any, namespace: str, nats_server: str, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    bed = Bed(k8s, namespace)
    try:
        tenant = Tenant(k8s, namespace)
        client = tenant.client()
        spec = JobSpec(image="localhost/pick:dev", embodiment=bed.embodiment)
        with running_operator(k8s, namespace, monkeypatch):
            cell = bed.cell("only")
            client.submit(spec, name="first")
            eventually("first bound", lambda: client.get("first").status is JobStatus.DISPATCHED)
            client.submit(spec, name="second")
            client.submit(spec, name="third")
            queued = eventually("third queued behind second", lambda: (
                v := client.describe("third")).queue_position == 2 and v)
            client.cancel("third")
            # What an agent would have streamed for this job: wait() returns it whole.
            uid = client.read("third").metadata.uid
            assert uid
            Publisher(nats_server, namespace, uid).publish(
                stdout_lines(1, 3) + [("stderr", 1, b"warn")])
            client.nats_url = nats_server
            result = client.wait("third", timeout=30)
        # KopfRunner swaps sys.stdout while it runs: the CLI is asked once it stopped.
        capsys.readouterr()
        assert tenant.cli("get") == 0
        rows = {line.split()[0]: line.split() for line in capsys.readouterr().out.splitlines()[1:]}
        assert tenant.cli("cells") == 0
        cells = {line.split()[0]: line.split() for line in capsys.readouterr().out.splitlines()[1:]}
        assert tenant.cli("result", "third") == 1
    finally:
        bed.close()

    assert (queued.status, queued.queued_reason) == (JobStatus.QUEUED, "AllCellsBusy")
    assert result.status is JobStatus.CANCELLED
    assert (result.stdout, result.stderr) == ("line 1\nline 2\nline 3\n", "warn\n")
    assert rows["first"][1:3] == ["dispatched", cell]
    # Behind "first", which holds the cell for its timeout (120 s) and the cell's grace (10 s) at the latest.
    assert rows["second"][1:2] + rows["second"][4:8] == ["queued", "AllCellsBusy", "#1,", "starts", "within"]
    assert rows["second"][8] == "2m" or rows["second"][8].endswith("s"), rows["second"]
    assert rows["third"][1] == "cancelled"
    assert cells[cell][1] == "Busy" and cells[cell][4] == f"{namespace}/first"


def test_execute_follows_until_the_operator_cancels_and_raise_for_status_raises(
    k8s: Any, namespace: str, nats_server: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    tenant = Tenant(k8s, namespace)
    client = tenant.client()
    client.nats_url = nats_server
    canceller = tenant.client()
    spec = JobSpec(image="localhost/pick:dev", embodiment=f"test/none-{namespace}")

    def cancel_when_queued() -> None:
        job = eventually("a queued job", lambda: next(
            (j for j in canceller.list_jobs() if j.status.queued_reason), None))
        canceller.cancel(job.metadata.name)

    with running_operator(k8s, namespace, monkeypatch):
        worker = threading.Thread(target=cancel_when_queued, daemon=True)
        worker.start()
        result = client.execute(spec, follow=True)
        worker.join(10)

    assert result.status is JobStatus.CANCELLED
    with pytest.raises(RemoteExecutionError, match="status=cancelled"):
        result.raise_for_status()


def test_following_a_job_the_operator_cancelled_while_queued_says_why_it_ended(
    k8s: Any, namespace: str, nats_server: str, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """No agent ever had the job, so its stream says nothing: the follow's last line comes from its status."""
    tenant = Tenant(k8s, namespace)
    client = tenant.client()
    client.nats_url = nats_server
    Publisher(nats_server, namespace, "none").publish([])  # the log stream exists, as on any cluster with agents
    with running_operator(k8s, namespace, monkeypatch):
        client.submit(JobSpec(image="localhost/pick:dev", embodiment=f"test/none-{namespace}"), name="never-ran")
        eventually("the job queued", lambda: client.describe("never-ran").queued_reason)
        client.cancel("never-ran")
        eventually("the job cancelled", lambda: client.get("never-ran").status is JobStatus.CANCELLED)
    lines = list(client.logs("never-ran", follow=True))
    capsys.readouterr()  # KopfRunner swapped sys.stdout while it ran: the CLI is asked once it stopped
    assert tenant.cli("logs", "-f", "never-ran", "--no-timestamps", "--nats-url", nats_server) == 0
    printed = capsys.readouterr().out

    assert [(x.kind, x.text, x.reason, x.source) for x in lines] == [
        ("status", "status: cancelled", "the job was cancelled before it started", "status")]
    assert printed == "[status: cancelled] the job was cancelled before it started\n"
