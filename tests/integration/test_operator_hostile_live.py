"""Hostile RobotJobs and Cells against the real API server with the operator running.

The CRD rejects what it can, naming the field; what only the operator can judge
(args depth and size, ports shared across cells of a node, a status that lies
about the claim, a timestamp the API server accepts but no datetime can hold)
fails or is repaired with a reason, while other jobs keep binding.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
import yaml
from armnet_core.api import API_VERSION, GROUP, ROBOTJOBS, VERSION

from tests.integration.operator_bed import Bed

pytestmark = pytest.mark.integration


def deep_json(levels: int) -> str:
    """Built as text: encoding a 1,000-level dict would itself need the recursion headroom."""
    return '{"a":' * (levels - 1) + '{"leaf":1}' + "}" * (levels - 1)


def rejected(bed: Bed, doc: dict[str, Any]) -> str:
    result = bed.k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(doc), check=False)
    assert result.returncode != 0, f"accepted: {doc}"
    return str(result.stderr)


def cell_doc(name: str, **spec: Any) -> dict[str, Any]:
    return {"apiVersion": API_VERSION, "kind": "Cell", "metadata": {"name": name},
            "spec": {"embodiment": "lerobot/so-101", "nodeName": "h", **spec}}


# ---------------------------------------------------------------- the CRDs bound every number and path
@pytest.mark.parametrize(("spec", "says"), [
    ({"ttlSecondsAfterFinished": 9223372036854775807}, "spec.ttlSecondsAfterFinished"),
    ({"timeoutSeconds": 10**12}, "spec.timeoutSeconds"),
    ({"priority": -(10**9)}, "spec.priority"),
])
def test_job_numbers_beyond_their_maximum_are_rejected_naming_the_field(
    bed: Bed, spec: dict[str, Any], says: str
) -> None:
    doc = {"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": "big", "namespace": bed.ns},
           "spec": {"image": "localhost/armnet-test:dev", "embodiment": bed.embodiment, **spec}}
    assert says in rejected(bed, doc)


@pytest.mark.parametrize(("spec", "says"), [
    ({"robot": {"safetyLimit": 1e9}}, "spec.robot.safetyLimit"),
    ({"robot": {"calibrationDir": "../../etc/passwd"}}, "spec.robot.calibrationDir: Invalid value"),
    ({"robot": {"calibrationDir": "/var/lib/../../etc"}}, "without '..' segments"),
    ({"robot": {"port": "ttyACM0"}}, "spec.robot.port"),
    ({"gracePeriodSeconds": 10**9}, "spec.gracePeriodSeconds"),
    ({"resetTimeoutSeconds": 10**9}, "spec.resetTimeoutSeconds"),
    ({"cameras": {"front": {"indexOrPath": 0, "fps": 10**6}}}, "spec.cameras.front.fps"),
    ({"embodiment": "lerobot/bimanual_so101",
      "arms": {"left": {"port": "/dev/a", "robotId": "l"}, "right": {"port": "/dev/a", "robotId": "r"}}},
     "each arm of a cell needs its own port"),
    ({"embodiment": "lerobot/bimanual_so101",
      "arms": {"left": {"port": "/dev/a", "robotId": "x"}, "right": {"port": "/dev/b", "robotId": "x"}}},
     "each arm of a cell needs its own robotId"),
    ({"embodiment": "lerobot/bimanual_so101",
      "arms": {"left": {"safetyLimit": 1e9}, "right": {}}}, "spec.arms.left.safetyLimit"),
])
def test_bad_cells_are_rejected_naming_the_field(bed: Bed, spec: dict[str, Any], says: str) -> None:
    assert says in rejected(bed, cell_doc(f"bad-{bed.ns}", **spec))


# ---------------------------------------------------------------- deep and huge args
def test_args_a_thousand_levels_deep_fail_the_job_and_the_operator_keeps_binding(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")
    head = json.dumps({"apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": "deep", "namespace": bed.ns},
                       "spec": {"image": "localhost/armnet-test:dev", "embodiment": bed.embodiment}})
    doc = head[:-2] + ', "args": ' + deep_json(1000) + "}}"
    bed.k8s.kubectl("create", "-f", "-", input=doc)
    bed.job("after-deep")
    bed.wait_job("after-deep", phase="dispatched", cellName=cell)
    body = bed.wait_job("deep", phase="failed")
    queued = bed.condition(body, "Queued")
    assert queued["reason"] == "InvalidSpec" and "spec.args is nested more than 32 levels" in queued["message"]
    assert "nested more than 32 levels" in body["status"]["result"]["error"]
    assert not operator.dead


def test_a_megabyte_of_args_fails_the_job_saying_the_limit(bed: Bed, operator: Any) -> None:
    # Created, not applied: kubectl apply would keep a copy in an annotation (256 KiB at most).
    bed.api.create_namespaced_custom_object(GROUP, VERSION, bed.ns, ROBOTJOBS, {
        "apiVersion": API_VERSION, "kind": "RobotJob", "metadata": {"name": "huge"},
        "spec": {"image": "localhost/armnet-test:dev", "embodiment": bed.embodiment, "args": {"blob": "x" * (1 << 20)}}})
    body = bed.wait_job("huge", phase="failed")
    assert "larger than 65536 bytes" in bed.condition(body, "Queued")["message"]
    bed.wait("an InvalidSpec event", lambda: "InvalidSpec" in bed.events("huge"))  # posted after the phase


# ---------------------------------------------------------------- ports across cells of one node
def test_a_second_cell_on_the_same_port_of_a_node_is_invalid_and_never_bound(bed: Bed, operator: Any) -> None:
    port = {"port": f"/dev/tty-{bed.ns}", "robotId": "r"}
    first = bed.cell("a-first")
    bed.k8s.kubectl("patch", "cell", first, "--type=merge", "-p", json.dumps({"spec": {"robot": port}}))
    second = bed.cell("b-second")
    bed.k8s.kubectl("patch", "cell", second, "--type=merge", "-p", json.dumps({"spec": {"robot": port}}))
    status = bed.wait("the second cell Invalid", lambda: (
        s if (s := bed.get_cell(second).get("status", {})).get("phase") == "Invalid" else None))
    assert f"already used by cell {first}" in status["message"]
    bed.job("j1")
    bed.job("j2")
    bed.wait_job("j1", phase="dispatched", cellName=first)
    bed.wait_job("j2", phase="queued", queuedReason="AllCellsBusy")
    assert not bed.get_cell(second)["status"].get("currentJob")


# ---------------------------------------------------------------- the claim is the one truth; status repaired
def test_a_job_patched_to_running_on_a_cell_that_holds_another_fails_with_the_reason(bed: Bed, operator: Any) -> None:
    cell = bed.cell("c1")
    bed.job("holder")
    bed.wait_job("holder", phase="dispatched", cellName=cell)
    bed.agent_sets("holder", "running")
    bed.job("intruder", priority=-1)
    bed.wait_job("intruder", phase="queued")
    bed.agent_sets("intruder", "running", cellName=cell)
    body = bed.wait_job("intruder", phase="failed")
    assert f"does not hold this job's claim (it holds {bed.ns}/holder)" in body["status"]["result"]["error"]
    assert bed.get_job("holder")["status"]["phase"] == "running"
    assert bed.get_cell(cell)["status"]["currentJob"] == f"{bed.ns}/holder"


def test_a_status_timestamp_no_datetime_can_hold_is_repaired_and_the_finalizer_still_goes(
    bed: Bed, operator: Any
) -> None:
    cell = bed.cell("c1")
    bed.job("odd")
    bed.wait_job("odd", phase="dispatched", cellName=cell)
    bed.wait("the finalizer", lambda: (bed.get_job("odd") or {}).get("metadata", {}).get("finalizers"))
    # The API server accepts year 0 as a date-time; Python's datetime starts at year 1.
    bed.agent_sets("odd", "running")
    bed.agent_sets("odd", "succeeded")
    bed.api.patch_namespaced_custom_object_status(GROUP, VERSION, bed.ns, ROBOTJOBS, "odd",
                                                  {"status": {"finishedAt": "0000-01-01T00:00:00Z"}})
    bed.wait("the StatusRepaired event", lambda: "StatusRepaired" in bed.events("odd"))
    assert "finishedAt" not in bed.get_job("odd")["status"]
    bed.k8s.kubectl("delete", "robotjob", "odd", "-n", bed.ns, "--wait=false")
    bed.wait("the job gone (its finalizer removed)", lambda: bed.get_job("odd") is None)
    bed.wait("the cell released", lambda: not bed.get_cell(cell)["status"].get("currentJob"))
