"""The scenarios every launcher must pass, written once and run by each launcher's module.

``e2e/test_agent_jobs.py`` runs them with the agent's container launcher (Podman),
``e2e/test_pod_jobs.py`` with its pod launcher (the test bed's node): the two modules live
in different test sessions (the pod bed holds the host's node), so each module calls these
on its own bed and adds what only its launcher has (a pod's shape, the device plugin's
allocation, a container's stream). A scenario returns what it read, for those additions.

What differs between launchers is passed in, with the measurement behind it where it is a
bound: a job's status is written when the launcher has seen the job end, which for a pod
takes the kubelet's kill and the pod's exit being seen.
"""

from __future__ import annotations

import json
from datetime import datetime
from typing import Any

from armnet_core.times import parse_time

from e2e.agent_bed import JOBS, AgentBed


def status(job: dict[str, Any]) -> dict[str, Any]:
    return job.get("status") or {}


def explain(st: dict[str, Any]) -> str:
    """The parts of a status that say why a job ended (error, traceback, the output's end)."""
    result = st.get("result") or {}
    return (f"phase {st.get('phase')}\nerror: {result.get('error')}\ntraceback: {result.get('traceback')}\n"
            f"stdout tail: {(result.get('stdoutTail') or '')[-4000:]}")


def moment_of(value: str) -> datetime:
    """The moment a status's timestamp names; a status time that is not one fails the test."""
    moment = parse_time(value)
    assert moment is not None, f"not a time: {value!r}"
    return moment


def seconds_between(start: str, end: str) -> float:
    return (moment_of(end) - moment_of(start)).total_seconds()


def a_bus_loop_job_succeeds_with_its_return_value(bed: AgentBed, name: str, *,
                                                 within_s: float = 300) -> dict[str, Any]:
    """The bus-loop example (LeRobot's own bus through the connector): its final positions, exit 0."""
    st = status(bed.wait_phase(name, timeout=within_s))
    assert st["phase"] == "succeeded", explain(st)
    finals = st["result"]["returnValue"]["final_positions"]
    assert set(finals) >= {"shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"}
    assert st["result"]["exitCode"] == 0
    assert st["startedAt"] <= st["finishedAt"]
    return st


def a_bus_loop_job_s_servo_trace_is_stored_and_agrees_with_it(
    st: dict[str, Any], object_store: Any, bucket: str, prefix: str,
) -> list[str]:
    """The cell's servo trace of the bus-loop job, read from the store: the job's last read of each motor is
    the positions it returned, and its goals are there. Returns every path the job's manifest lists."""
    import io

    import pyarrow as pa
    import pyarrow.parquet as pq
    import pytest

    s3 = object_store.client()
    manifest = json.loads(s3.get_object(Bucket=bucket, Key=prefix + "manifest.json")["Body"].read())
    paths = sorted(f["path"] for f in manifest["files"])
    parts = [pq.read_table(io.BytesIO(s3.get_object(Bucket=bucket, Key=prefix + "files/" + path)["Body"].read()))
             for path in paths if path.startswith("armnet-cell/servo-trace/")]
    assert parts, paths
    trace = pa.concat_tables(parts).to_pylist()
    finals = st["result"]["returnValue"]["final_positions"]
    last = {r["motor"]: r["value"] for r in trace if r["kind"] == "present_position" and r["motor"] in finals}
    assert last == pytest.approx(finals, abs=0.01), (last, finals)  # the job rounds to 2 places
    assert any(r["kind"] == "goal_position" for r in trace)
    return paths


def a_job_that_raises_fails_with_its_traceback(bed: AgentBed, name: str, *, within_s: float = 300) -> dict[str, Any]:
    """``jobs/raises.py``: failed, its traceback and what it printed before in the status."""
    st = status(bed.wait_phase(name, timeout=within_s))
    assert st["phase"] == "failed", explain(st)
    assert "ValueError: the gripper saw no cube" in st["result"]["traceback"]
    assert "about to fail" in st["result"]["stdoutTail"]
    return st


def a_missing_secret_fails_the_job_before_it_starts(bed: AgentBed, name: str) -> dict[str, Any]:
    """A job naming a Secret its namespace lacks: failed, the error naming it; it never started."""
    job = bed.wait_phase(name, timeout=300)
    st = status(job)
    assert st["phase"] == "failed", explain(st)
    assert "'absent'" in st["result"]["error"] and bed.namespace in st["result"]["error"]
    assert "startedAt" not in st
    return job


def a_safety_violation_fails_the_job_and_the_interlock_clears(bed: AgentBed, name: str, *,
                                                              within_s: float = 300) -> dict[str, Any]:
    """``jobs/unsafe.py``: failed with ``SafetyViolation``; the interlock's reason is the connector's own record."""
    st = status(bed.wait_phase(name, timeout=within_s))
    assert st["phase"] == "failed", explain(st)
    assert "SafetyViolation" in st["result"]["traceback"]
    bed.assert_safety_violation_then_interlock_clears(st)
    return st


def a_job_ignoring_shutdown_is_killed_at_the_end_of_grace(bed: AgentBed, name: str, *, job_timeout: int,
                                                          end_seen_s: float) -> dict[str, Any]:
    """``jobs/ignores_shutdown.py``: ``timeout`` after the cell's whole grace window (3 s), then the kill.

    ``end_seen_s``: what the launcher may take, after the kill, to see the job end and
    write it (its measurement is the caller's).
    """
    st = status(bed.wait_phase(name, timeout=300))
    assert st["phase"] == "timeout", explain(st)
    assert "killed at the end of the 3 s grace window" in st["result"]["error"]
    assert seconds_between(st["startedAt"], st["finishedAt"]) <= job_timeout + 3 + end_seen_s, explain(st)
    return st


def a_bimanual_job_runs_on_the_bimanual_cell(bed: AgentBed, name: str, *, within_s: float = 300) -> dict[str, Any]:
    st = status(bed.wait_phase(name, timeout=within_s))
    assert st["phase"] == "succeeded", explain(st)
    assert st["cellName"] == bed.bimanual  # type: ignore[attr-defined]
    return st


def an_agent_killed_mid_job_readopts_it_and_reports_every_line_once(
        bed: AgentBed, *, lines: int, output_within_s: float) -> dict[str, Any]:
    """The agent is killed while a job prints and started again: it adopts the running job,
    and the status holds every line once, in order, and the job's own return value."""
    image = bed.image("counts", JOBS / "counts_slowly.py")
    bed.submit("survives", image, args={"lines": lines, "pause": 0.25}, timeout=200)
    bed.wait_phase("survives", ("running",), timeout=300)

    def some_output() -> bool:
        progress = status(bed.job("survives")).get("progress") or ""
        return progress.startswith("line ") and int(progress.split()[1]) >= 5

    bed.wait(some_output, output_within_s, "some output")
    bed.kill_agent()
    bed.start_agent()
    st = status(bed.wait_phase("survives", timeout=300))
    assert st["phase"] == "succeeded", explain(st)
    assert st["result"]["returnValue"] == {"lines": lines}
    printed = [line.split(" ", 1)[-1] for line in st["result"]["stdoutTail"].splitlines()]  # after the timestamp
    assert [line for line in printed if line.startswith("line ")] == [f"line {i:03d}" for i in range(lines)]
    return st
