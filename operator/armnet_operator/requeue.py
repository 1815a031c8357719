"""The RobotJob that runs a preempted job again: its name and body, built purely from the preempted job.

A preempted job ends ``preempted`` with its partial result, like any finished job:
its status, logs and outputs stay where its run left them. When its spec asks for
it (``requeueOnPreemption``, the default), the operator creates a copy that waits
in the queue in its place, as a Kubernetes Job replaces an evicted Pod. A copy, not
the same object put back: every record of a run (the node agent's container or
pod, its output directory, the stream ids of its log lines) is keyed by the job's
uid, and a second run under the same uid would collide with the first one's.

The copy keeps the preempted job's place: ``armnet.io/queued-since`` carries when
the first of the chain joined the queue, which the scheduler orders by
(``parsing.queued_since``). ``armnet.io/preempted-from`` carries the preempted
job's uid, so a copy the operator created before a crash is found and adopted
instead of created twice.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from datetime import datetime
from typing import Any

from armnet_core.api import API_VERSION, GROUP, PREEMPTED_FROM_ANNOTATION, QUEUED_SINCE_ANNOTATION
from armnet_core.times import kube_time

MAX_NAME = 253
_ATTEMPT = re.compile(r"^(?P<base>.+)-r(?P<n>[1-9][0-9]{0,5})$")
#: Annotations that describe one object, not the job: not copied (kubectl's last-applied
#: configuration would make the copy look like the tenant's own manifest).
_NOT_COPIED = (f"{GROUP}/", "kubectl.kubernetes.io/")


def requeue_name(name: str, uid: str, taken_by_other: bool = False) -> str:
    """``pick`` -> ``pick-r1`` -> ``pick-r2``; with ``taken_by_other`` (a tenant's own job has that
    name), the preempted job's uid prefix makes it unique."""
    found = _ATTEMPT.match(name)
    base, attempt = (found["base"], int(found["n"]) + 1) if found else (name, 1)
    suffix = f"-r{attempt}" + (f"-{uid[:8]}" if taken_by_other else "")
    return base[: MAX_NAME - len(suffix)].rstrip("-.") + suffix


def requeue_body(preempted: Mapping[str, Any], name: str, queued_since: datetime) -> dict[str, Any]:
    """The copy of ``preempted`` (a RobotJob as the server returned it) to create as ``name``."""
    meta = preempted.get("metadata") or {}
    annotations = copied_annotations(meta)
    annotations[PREEMPTED_FROM_ANNOTATION] = str(meta.get("uid", ""))
    annotations[QUEUED_SINCE_ANNOTATION] = kube_time(queued_since)
    spec = dict(preempted.get("spec") or {})
    spec["cancel"] = False
    # It ran on a real cell, so its pre-flight (``preflight``) passed: the copy runs the same program again.
    spec.pop("preflight", None)
    return {
        "apiVersion": API_VERSION,
        "kind": "RobotJob",
        "metadata": {
            "name": name,
            "namespace": meta.get("namespace"),
            "labels": dict(meta.get("labels") or {}),
            "annotations": annotations,
        },
        "spec": spec,
    }


def copied_annotations(meta: Mapping[str, Any]) -> dict[str, str]:
    """The annotations of a job its copies keep: the tenant's own, not the ones that describe one object."""
    return {k: v for k, v in (meta.get("annotations") or {}).items() if not k.startswith(_NOT_COPIED)}


def is_requeue_of(candidate: Mapping[str, Any], uid: str) -> bool:
    """Whether ``candidate`` is the copy created for the job with ``uid`` (before a crash, or by another replica)."""
    annotations = (candidate.get("metadata") or {}).get("annotations") or {}
    return bool(uid) and annotations.get(PREEMPTED_FROM_ANNOTATION) == uid


__all__ = ["copied_annotations", "is_requeue_of", "requeue_body", "requeue_name"]
