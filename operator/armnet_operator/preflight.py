"""A job's pre-flight on a simulated twin: the pre-flight RobotJob's name and body, and the verdict.

A RobotJob with ``spec.preflight`` first runs as a second RobotJob, its pre-flight,
which the scheduler binds only to a pre-flight Cell (``spec.preflight: true``, always
simulated) of the job's embodiment. Only when the pre-flight passes does the job join
the queue for a real cell; when it fails, the job fails (``PreflightFailed``) without
costing real cell time. A separate object, not a second run of the same one, for the
reason a preempted job's requeue is one (``requeue``): every record of a run (its
container or pod, its output directory, its log stream's ids, its ``status.result``
with the safety record) is keyed by the job's uid, and the pre-flight's records must
stay readable beside the real run's.

Pure: this module builds bodies and decides verdicts; ``reconcile`` writes them. The
pre-flight carries ``armnet.io/preflight-for: <the job's uid>``, so one created before a
crash is found and adopted instead of created twice.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from armnet_core.api import API_VERSION, PREFLIGHT_FOR_ANNOTATION, PreflightPhase
from armnet_core.times import kube_time

from .model import Job, JobPhase
from .requeue import MAX_NAME, copied_annotations

SUFFIX = "-preflight"
#: The reason a job whose pre-flight failed ends with (its Queued condition, its Event).
PREFLIGHT_FAILED = "PreflightFailed"
#: ``status.preflight.message`` is bounded by the CRD.
MAX_MESSAGE = 1024


def preflight_name(name: str, uid: str, taken_by_other: bool = False) -> str:
    """``pick`` -> ``pick-preflight``; with ``taken_by_other`` (a tenant's own job has that name),
    the job's uid prefix makes it unique."""
    suffix = SUFFIX + (f"-{uid[:8]}" if taken_by_other else "")
    return name[: MAX_NAME - len(suffix)].rstrip("-.") + suffix


def preflight_body(job: Mapping[str, Any], name: str) -> dict[str, Any]:
    """The pre-flight of ``job`` (a RobotJob as the server returned it), to create as ``name``.

    The same image, args, secrets, embodiment, task and priority (the same connector,
    limits and SDK: the twin is a Cell of the same embodiment), with: no pre-flight of
    its own, not cancelled, at most ``spec.preflight.seconds`` (or the job's own timeout
    if shorter), never requeued when preempted. Owned by the job, so deleting the job
    (its TTL too) deletes its pre-flight.
    """
    meta = job.get("metadata") or {}
    spec = dict(job.get("spec") or {})
    seconds = int((spec.pop("preflight", None) or {}).get("seconds", 1))
    spec["cancel"] = False
    spec["requeueOnPreemption"] = False
    spec["timeoutSeconds"] = min(int(spec.get("timeoutSeconds", seconds)), seconds)
    annotations = copied_annotations(meta)
    annotations[PREFLIGHT_FOR_ANNOTATION] = str(meta.get("uid", ""))
    return {
        "apiVersion": API_VERSION,
        "kind": "RobotJob",
        "metadata": {
            "name": name,
            "namespace": meta.get("namespace"),
            "labels": dict(meta.get("labels") or {}),
            "annotations": annotations,
            "ownerReferences": [{"apiVersion": API_VERSION, "kind": "RobotJob", "name": meta.get("name"),
                                 "uid": meta.get("uid")}],
        },
        "spec": spec,
    }


def is_preflight_of(candidate: Mapping[str, Any], uid: str) -> bool:
    """Whether ``candidate`` is the pre-flight created for the job with ``uid`` (before a crash, or by another replica)."""
    annotations = (candidate.get("metadata") or {}).get("annotations") or {}
    return bool(uid) and annotations.get(PREFLIGHT_FOR_ANNOTATION) == uid


@dataclass(frozen=True)
class Verdict:
    """What a finished pre-flight says about its job: ``passed``, and why in words."""

    passed: bool
    message: str

    @property
    def label(self) -> str:
        """The verdict as ``armnet_preflights_total`` counts it."""
        return self.phase.value.lower()

    @property
    def phase(self) -> PreflightPhase:
        return PreflightPhase.PASSED if self.passed else PreflightPhase.FAILED


def judge(preflight: Job | None, name: str, error: str | None = None, traceback: str | None = None,
          device_calls: int | None = None) -> Verdict | None:
    """The verdict on the pre-flight ``name`` (None: it is gone), or None while it has not finished.

    ``error``, ``traceback`` and ``device_calls`` are the pre-flight's ``status.result``
    (``device_calls``: its connector record's ``safety.deviceCalls``, ``device_calls_of``;
    the frozen ``Job`` does not carry them). Succeeded: passed. Ran its whole time
    (``timeout``): passed if it reached the twin's devices; one that made no call to them
    (still importing, or waiting on something else, when its seconds ran out) proved
    nothing and fails, saying to give the pre-flight more seconds; a record that does not
    say (an agent from before the count) passes, as before. Failed: failed, with its error
    (or its traceback's last line). Cancelled or preempted (a pre-flight is neither
    preempted nor requeued by the operator; a person cancelled it): failed, as one that is gone.
    """
    if preflight is None:
        return Verdict(False, f"the pre-flight job {name} no longer exists")
    if not preflight.terminal:
        return None
    where = f" on pre-flight cell {preflight.cell_name}" if preflight.cell_name else ""
    match preflight.phase:
        case JobPhase.SUCCEEDED:
            return Verdict(True, f"the pre-flight job {name} succeeded{where}")
        case JobPhase.TIMEOUT if device_calls == 0:
            return Verdict(False, f"the pre-flight job {name} ran the pre-flight's {preflight.timeout_seconds} s{where} "
                                  "without reaching the cell (no call to its bus or cameras), which proves nothing: "
                                  "give spec.preflight.seconds more time than the job takes to start")
        case JobPhase.TIMEOUT:
            calls = f", {device_calls} call(s) to the twin's devices" if device_calls else ""
            return Verdict(True, f"the pre-flight job {name} ran the pre-flight's {preflight.timeout_seconds} s "
                                 f"without failing{where}{calls}")
        case JobPhase.FAILED:
            why = error or _last_line(traceback) or "it failed without an error message"
            return Verdict(False, _bounded(f"the pre-flight job {name} failed{where}: {why}"))
    if preflight.phase is JobPhase.CANCELLED:
        return Verdict(False, f"the pre-flight job {name} was cancelled")
    return Verdict(False, f"the pre-flight job {name} was stopped ({preflight.phase}) before it could pass")


def device_calls_of(result: Mapping[str, Any]) -> int | None:
    """``safety.deviceCalls`` of a job's ``status.result``: a count, or None when the record has none."""
    safety = result.get("safety")
    calls = safety.get("deviceCalls") if isinstance(safety, Mapping) else None
    return calls if type(calls) is int and calls >= 0 else None


def _last_line(text: str | None) -> str | None:
    lines = [line.strip() for line in (text or "").splitlines() if line.strip()]
    return lines[-1] if lines else None


def _bounded(message: str) -> str:
    return message if len(message) <= MAX_MESSAGE else message[: MAX_MESSAGE - 3] + "..."


def started_status(name: str, now: datetime) -> dict[str, Any]:
    """``status.preflight`` once the pre-flight exists: the job waits for its verdict."""
    return {"phase": PreflightPhase.RUNNING.value, "job": name, "startedAt": kube_time(now),
            "message": f"the pre-flight job {name} runs on a simulated twin; the job joins the queue once it passes"}


def verdict_status(name: str, verdict: Verdict, now: datetime) -> dict[str, Any]:
    """``status.preflight`` with the verdict (merged over ``started_status``: ``startedAt`` stays)."""
    return {"phase": verdict.phase.value, "job": name, "message": verdict.message, "finishedAt": kube_time(now)}


def failed_error(verdict: Verdict) -> str:
    """The job's ``result.error`` when its pre-flight failed: the verdict, which names the pre-flight job."""
    return f"pre-flight failed: {verdict.message} (see that job's status for its logs, result and safety record)"


def needs_start(job: Job) -> bool:
    """A waiting job that asks for a pre-flight and has none yet."""
    return job.preflight_seconds is not None and job.preflight_phase is None and job.waiting


def needs_cancel(preflight: Job, owner: Job | None) -> bool:
    """A pre-flight still running (or waiting) whose job is gone, cancelled, deleted or over: stop it."""
    if preflight.terminal or preflight.cancel or preflight.deleting:
        return False
    return owner is None or owner.cancel or owner.deleting or owner.terminal


__all__ = [
    "PREFLIGHT_FAILED",
    "Verdict",
    "device_calls_of",
    "failed_error",
    "is_preflight_of",
    "judge",
    "needs_cancel",
    "needs_start",
    "preflight_body",
    "preflight_name",
    "started_status",
    "verdict_status",
]
