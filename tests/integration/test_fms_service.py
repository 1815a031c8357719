"""``armnet fms`` against the real apiserver and NATS, with the agent's real operator-inputs bridge.

The FMS process runs as a least-privileged user (``FMS_RULES``, what the chart's
ClusterRole should grant). The job side is the agent's own
``OperatorInputsBridge`` feeding a ``LocalOperatorInputs``: exactly what a
running job's connector waits on; its verdicts go to the agent's
``RolloutRecorder`` and the runner's ``write_progress`` writes the history into
the job's status, over rollout events shaped as the connector records them.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import httpx
import pytest
from armnet_connector.cell import RolloutEvent
from armnet_connector.inputs import LocalOperatorInputs
from armnet_core.api import STOPPED_BY_ANNOTATION
from armnet_core.times import kube_time
from armnet_node.inputs_bridge import OperatorInputsBridge
from armnet_node.kube import AgentKube
from armnet_node.model import parse_job
from armnet_node.rollout_recorder import RolloutRecorder
from armnet_node.runner import write_progress
from armnet_node.streams import NatsLink, StreamSettings

from tests.support.fms_objects import (
    a_cell,
    a_job,
    apply,
    cell_busy,
    events_about,
    get,
    grant_fms,
    running_on,
)
from tests.support.fms_server import OPERATOR, TOKEN, FmsServer
from tests.support.waiting import wait_for

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]


class Bed:
    """One cell running one job (statuses as the operator and agent write them), the FMS, the job's bridge."""

    def __init__(self, k8s: Any, namespace: str, nats_url: str, fms: FmsServer) -> None:
        self.k8s, self.namespace, self.fms = k8s, namespace, fms
        self.cell = f"fms-{uuid.uuid4().hex[:6]}"
        apply(k8s, a_cell(self.cell, reset_timeout=3))
        job = apply(k8s, a_job("eval-1", namespace))
        self.job_id = running_on(k8s, self.cell, job, rollout={"index": 2, "total": 5})
        cell_busy(k8s, self.cell, f"{namespace}/eval-1", heartbeat=kube_time(datetime.now(UTC)))
        self.inputs = LocalOperatorInputs()
        #: The connector's rollout record: the job is in rollout 2 of 5.
        self.rollout_events = [RolloutEvent("begin", time.time(), 2, 5, True)]
        self.rollouts = RolloutRecorder(lambda: list(self.rollout_events))
        self.link = NatsLink(StreamSettings(url=nats_url)).start()
        self.bridge = OperatorInputsBridge(self.link, self.inputs, namespace=namespace, job_uid=self.job_id,
                                           cell=self.cell, on_verdict=self.rollouts.verdict,
                                           on_overrule=self.rollouts.overrule).start()
        assert self.bridge.wait_active(20)
        self.http = httpx.Client(base_url=fms.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=10)

    def row(self) -> dict[str, Any] | None:
        cells = self.http.get("/api/fleet").json()["cells"]
        return next((c for c in cells if c["name"] == self.cell), None)

    def act(self, action: str, **body: Any) -> httpx.Response:
        return self.http.post(f"/api/cells/{self.cell}/{action}", json=body)

    def write_rollouts(self) -> dict[str, Any]:
        """The agent's progress write (once a second in a running job), then the job as the API has it."""
        job = parse_job(get(self.k8s, "robotjob", "eval-1", self.namespace))
        write_progress(AgentKube(self.k8s.api_client()), job, None, {"index": 2, "total": 5}, self.rollouts,
                       force=False)
        return get(self.k8s, "robotjob", "eval-1", self.namespace)

    def close(self) -> None:
        self.http.close()
        self.bridge.close()
        self.link.stop()


@pytest.fixture(scope="module")
def fms(k8s: Any, nats_server: str) -> Iterator[FmsServer]:
    user = k8s.user("armnet-fms", groups=())
    grant_fms(k8s, "armnet-fms")
    server = FmsServer(user.kubeconfig, nats_server)
    yield server
    server.stop()


@pytest.fixture
def bed(k8s: Any, namespace: str, nats_server: str, fms: FmsServer) -> Iterator[Bed]:
    bed = Bed(k8s, namespace, nats_server, fms)
    # The cell and its job (two watches: on a loaded host the job can arrive a moment after the cell).
    wait_for(lambda: (row := bed.row()) and row["job"], what="the FMS to list the cell and its job")
    yield bed
    bed.close()


def reset_wait(inputs: LocalOperatorInputs, timeout_s: float) -> tuple[threading.Thread, list[bool]]:
    """A job's ``ctx.cell.reset()`` waiting, as the connector waits (in a thread)."""
    result: list[bool] = []
    thread = threading.Thread(target=lambda: result.append(inputs.wait_reset_confirmation(timeout_s)), daemon=True)
    thread.start()
    return thread, result


def test_the_fleet_shows_the_job_rollout_and_false_conditions(bed: Bed) -> None:
    row = bed.row()
    assert row is not None
    assert row["job"]["name"] == "eval-1" and row["job"]["tenant"] == bed.namespace
    assert (row["job"]["rolloutIndex"], row["job"]["rolloutTotal"]) == (2, 5)
    assert [c["type"] for c in row["falseConditions"]] == ["CamerasReady"]
    assert row["interlock"] == "clear" and row["site"] == "lab-1"


def test_a_confirmation_reaches_the_waiting_reset(bed: Bed) -> None:
    thread, result = reset_wait(bed.inputs, 20)
    row = wait_for(lambda: (r := bed.row()) and r["reset"] and r, what="the pending reset on the page")
    assert bed.act("confirm-reset", request=row["reset"]["request"]).status_code == 200
    thread.join(10)
    assert result == [True]


def test_a_stale_confirmation_never_confirms_the_next_reset(bed: Bed) -> None:
    thread, result = reset_wait(bed.inputs, 3)  # the cell's resetTimeoutSeconds
    first = wait_for(lambda: (r := bed.row()) and r["reset"] and r, what="the first reset")["reset"]["request"]
    thread.join(10)
    assert result == [False]  # nobody confirmed in time
    thread, result = reset_wait(bed.inputs, 20)
    second = wait_for(lambda: (r := bed.row()) and r["reset"] and r["reset"]["request"] != first and r,
                      what="the second reset")["reset"]["request"]
    late = bed.act("confirm-reset", request=first)
    assert late.status_code == 409 and "earlier reset" in late.json()["error"]
    assert bed.inputs.wait_reset_pending(0.5), "the stale click must leave the second reset waiting"
    assert bed.act("confirm-reset", request=second).status_code == 200
    thread.join(10)
    assert result == [True]


def test_fail_reaches_the_job_as_an_unsuccessful_outcome_and_is_audited(bed: Bed) -> None:
    assert bed.act("fail").status_code == 200
    wait_for(lambda: bed.bridge.accepted >= 1, what="the bridge to take the outcome")
    assert bed.inputs.take_outcome() is False
    events = wait_for(lambda: events_about(bed.k8s, bed.namespace, "eval-1"), what="the audit event")
    assert events[0]["reason"] == "RolloutMarked"
    assert events[0]["message"] == f"rollout 2/5 marked failure by cell operator {OPERATOR}"


def test_a_verdict_lands_in_the_jobs_rollout_history_naming_the_operator(bed: Bed) -> None:
    assert bed.act("fail", request="2").status_code == 200
    wait_for(lambda: bed.bridge.accepted >= 1, what="the bridge to take the outcome")
    [entry] = bed.write_rollouts()["status"]["rollouts"]
    assert (entry["index"], entry["total"], entry["outcome"], entry["markedBy"]) == (2, 5, "failure", OPERATOR)
    assert "markedAt" in entry and "endedAt" not in entry
    verdicts = wait_for(lambda: bed.row()["job"]["verdicts"], what="the verdict on the page")  # type: ignore[index]
    assert [(v["index"], v["outcome"], v["by"]) for v in verdicts] == [(2, "failure", OPERATOR)]


def test_once_the_rollout_ended_the_page_shows_it_ended_and_a_verdict_is_refused(bed: Bed) -> None:
    assert bed.row()["job"]["rolloutActive"] is True  # type: ignore[index]
    bed.rollout_events.append(RolloutEvent("end", time.time()))
    assert bed.write_rollouts()["status"]["rollouts"][0]["endedAt"]
    wait_for(lambda: bed.row()["job"]["rolloutActive"] is False, what="the page to see the end")  # type: ignore[index]
    late = bed.act("success", request="2")
    assert late.status_code == 409 and "has ended" in late.json()["error"]


def test_the_monitor_s_verdict_shows_on_the_page_and_an_overrule_is_recorded_and_audited(bed: Bed) -> None:
    # The monitor judged rollout 2 a success and the job moved on to rollout 3.
    now = time.time()
    bed.rollout_events += [RolloutEvent("verdict", now, 2, success=True, score=0.93), RolloutEvent("end", now),
                           RolloutEvent("begin", now + 0.01, 3, 5, True)]
    bed.write_rollouts()
    [judged] = wait_for(lambda: bed.row()["job"]["verdicts"], what="the monitor's verdict on the page")  # type: ignore[index]
    assert (judged["index"], judged["outcome"], judged["by"], judged["monitor"], judged["score"]) == (
        2, "success", "monitor", "success", 0.93)

    assert bed.act("overrule-fail", request=judged["request"]).status_code == 200
    wait_for(lambda: bed.bridge.accepted >= 1, what="the bridge to take the overrule")
    rollouts = bed.write_rollouts()["status"]["rollouts"]
    assert [(r["index"], r["outcome"], r.get("markedBy"), (r.get("monitor") or {}).get("outcome")) for r in rollouts] == [
        (2, "failure", OPERATOR, "success"), (3, "unmarked", None, None)]
    assert bed.inputs.take_outcome() is None  # the job, in rollout 3, is not told
    overruled = wait_for(lambda: [v for v in bed.row()["job"]["verdicts"] if v["overruled"]],  # type: ignore[index]
                         what="the overrule on the page")
    assert overruled[0]["by"] == OPERATOR
    events = wait_for(lambda: events_about(bed.k8s, bed.namespace, "eval-1"), what="the audit event")
    assert events[0]["reason"] == "RolloutOverruled"
    assert events[0]["message"] == (f"rollout 2/5 marked failure by cell operator {OPERATOR} over the monitor's "
                                    "success, score 0.93")
    # A rollout the monitor did not judge cannot be overruled.
    refused = bed.act("overrule-fail", request=f"3@{rollouts[1]['startedAt']}")
    assert refused.status_code == 409 and "no rollout the monitor judged" in refused.json()["error"]


def test_stop_cancels_the_job_and_names_the_operator(bed: Bed) -> None:
    assert bed.act("stop").status_code == 200
    job = get(bed.k8s, "robotjob", "eval-1", bed.namespace)
    assert job["spec"]["cancel"] is True
    assert job["metadata"]["annotations"][STOPPED_BY_ANNOTATION] == OPERATOR
    events = wait_for(lambda: events_about(bed.k8s, bed.namespace, "eval-1"), what="the audit event")
    assert (events[0]["type"], events[0]["message"]) == ("Warning", f"stopped by cell operator {OPERATOR}")


def test_cordon_and_uncordon_set_unschedulable_with_events_on_the_cell(bed: Bed) -> None:
    assert bed.act("cordon").status_code == 200
    assert get(bed.k8s, "cell", bed.cell)["spec"]["unschedulable"] is True
    assert bed.act("uncordon").status_code == 200
    assert get(bed.k8s, "cell", bed.cell)["spec"]["unschedulable"] is False
    events = wait_for(lambda: len(e := events_about(bed.k8s, "default", bed.cell)) >= 2 and e, what="events")
    assert sorted(e["reason"] for e in events) == ["Cordoned", "Uncordoned"]
    assert all(e["message"].endswith(f"by cell operator {OPERATOR}") for e in events)


def test_without_a_token_there_is_only_the_login_page(bed: Bed) -> None:
    with httpx.Client(base_url=bed.fms.url, timeout=10) as anonymous:
        assert anonymous.get("/").headers["location"] == "/login"
        assert anonymous.get("/api/fleet").status_code == 401
        assert anonymous.get("/live").status_code == 401
        assert anonymous.post(f"/api/cells/{bed.cell}/cordon").status_code == 401
        assert bed.cell not in anonymous.get("/login").text


def test_a_tenants_kubernetes_token_is_not_an_operator_token(bed: Bed, k8s: Any) -> None:
    tenant = k8s.user("tenant-a")
    with httpx.Client(base_url=bed.fms.url, timeout=10,
                      headers={"Authorization": f"Bearer {tenant.token}"}) as client:
        assert client.get("/api/fleet").status_code == 401


def test_a_session_post_without_the_csrf_token_is_refused_and_changes_nothing(bed: Bed) -> None:
    with httpx.Client(base_url=bed.fms.url, timeout=10) as browser:
        assert browser.post("/login", data={"token": TOKEN}).status_code == 303
        refused = browser.post(f"/api/cells/{bed.cell}/cordon", json={})
        assert refused.status_code == 403
    assert get(bed.k8s, "cell", bed.cell)["spec"].get("unschedulable") is False


def test_metrics_count_actions_by_result(bed: Bed) -> None:
    bed.act("cordon")
    bed.act("confirm-reset", request="nothing-waits")
    text = httpx.get(f"{bed.fms.url}/metrics").text
    assert 'armnet_fms_actions_total{action="cordon",result="ok"}' in text
    assert 'armnet_fms_actions_total{action="confirm-reset",result="refused"}' in text


def test_a_cells_camera_frame_and_servo_readings_reach_only_logged_in_operators(bed: Bed) -> None:
    import json

    import cv2
    import numpy as np

    ok, encoded = cv2.imencode(".jpg", np.full((24, 32, 3), 200, np.uint8))
    jpeg = bytes(encoded)
    reading = {"t": 0, "source": "idle", "arms": {"arm": {"motors": {
        "gripper": {"position": 2100, "load": 15, "temperature": 33}}}}}

    def served() -> httpx.Response | None:  # core NATS: sent again until the FMS has it
        bed.link.notify(f"telemetry.{bed.cell}.camera.front", jpeg)
        bed.link.notify(f"telemetry.{bed.cell}.servos", json.dumps(reading).encode())
        reply = bed.http.get(f"/api/cells/{bed.cell}/camera/front.jpg")
        return reply if reply.status_code == 200 else None

    reply = wait_for(served, what="the frame served by the FMS")
    assert ok and reply.content == jpeg and reply.headers["content-type"] == "image/jpeg"
    view = wait_for(lambda: (v := bed.http.get(f"/api/cells/{bed.cell}/telemetry").json())["series"] and v,
                    what="servo readings served by the FMS")
    assert view["series"][0]["points"][-1][1:] == [2100, 15, 33]
    assert '<meta name="telemetry" content="on">' in bed.http.get(f"/cells/{bed.cell}").text
    with httpx.Client(base_url=bed.fms.url, timeout=10) as anonymous:
        assert anonymous.get(f"/api/cells/{bed.cell}/camera/front.jpg").status_code == 401
        assert anonymous.get(f"/api/cells/{bed.cell}/telemetry").status_code == 401
