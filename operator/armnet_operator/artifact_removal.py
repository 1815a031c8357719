"""A job's stored outputs go with the job at its TTL, unless kept. Pure.

The node agent stores each ended job's output directory under ``<namespace>/<uid>/`` in
the object store and says so in ``status.artifacts.location`` (docs/outputs.md). When the
operator deletes a finished job at its ``ttlSecondsAfterFinished``, it removes that prefix
first, so a TTL bounds what the store holds as it bounds the API server's objects. It
waits while the agent still uploads (``Job.uploading``, ``lifecycle``); a job annotated
``armnet.io/keep-artifacts: "true"`` keeps its outputs. Nothing outside the job's own
prefix is ever removed: the location must be exactly the one the agent writes for the
job's namespace and uid, in the bucket the operator was given.
"""

from __future__ import annotations

import re

from .model import Job

#: Kubernetes' syntax of a namespace and a uid: a prefix built from them never reaches another's objects.
_NAMESPACE = re.compile(r"^[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?$")
_UID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9-]{0,127}$")


def outputs_prefix(job: Job, bucket: str | None) -> str | None:
    """The prefix to remove from ``bucket`` with ``job``, or None: no store, nothing stored, kept,
    or a location that is not this job's own prefix in this bucket."""
    if bucket is None or job.keep_artifacts or not job.artifacts_location:
        return None
    if not (_NAMESPACE.match(job.namespace) and _UID.match(job.uid)):
        return None
    prefix = f"{job.namespace}/{job.uid}/"
    return prefix if job.artifacts_location == f"s3://{bucket}/{prefix}" else None


__all__ = ["outputs_prefix"]
