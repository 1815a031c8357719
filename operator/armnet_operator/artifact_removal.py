"""A job's stored outputs go with the job at its TTL, unless kept. Pure.

The node agent stores each ended job's output directory under ``<namespace>/<uid>/`` in
the object store and says so in ``status.artifacts.location`` (docs/outputs.md). When the
operator deletes a finished job at its ``ttlSecondsAfterFinished``, it removes that prefix
first, so a TTL bounds what the store holds as it bounds the API server's objects. It
waits for the agent's upload to begin and to settle (``upload_pending``, bounded); a job annotated
``armnet.io/keep-artifacts: "true"`` keeps its outputs. Nothing outside the job's own
prefix is ever removed: the location must be exactly the one the agent writes for the
job's namespace and uid, in the bucket the operator was given.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from armnet_core.api import ArtifactsPhase
from armnet_core.output_keys import job_prefix

from .model import Job

#: How long after a job's end its TTL delete waits for the node agent to begin storing its outputs
#: (``status.artifacts`` appears): an agent uploads one job at a time, and one that is down uploads at
#: its restart. Past it, the job goes (an agent that stores it later leaves objects no one removes).
UPLOAD_START_WAIT = timedelta(minutes=10)
#: How long past its TTL an upload under way (``Uploading``, ``Retrying``) may hold the delete: an agent
#: gone for good, or a store that refuses for ever, never settles it.
UPLOAD_SETTLE_CAP = timedelta(hours=24)



def outputs_prefix(job: Job, bucket: str | None) -> str | None:
    """The prefix to remove from ``bucket`` with ``job``, or None: no store, nothing stored, kept,
    or a location that is not this job's own prefix in this bucket."""
    if bucket is None or job.keep_artifacts or not job.artifacts_location:
        return None
    try:
        prefix = job_prefix(job.namespace, job.uid)
    except ValueError:
        return None
    return prefix if job.artifacts_location == f"s3://{bucket}/{prefix}" else None


def upload_pending(job: Job, now: datetime, ttl_end: datetime) -> bool:
    """Whether the job's TTL delete (due at ``ttl_end``) waits for its upload, so nothing is stored after
    the removal: one under way, up to ``UPLOAD_SETTLE_CAP`` past the TTL; none begun yet (no
    ``status.artifacts``, or ``Pending``: waiting in the agent's queue), up to ``UPLOAD_START_WAIT``
    after the job ended."""
    if job.uploading:
        return now < ttl_end + UPLOAD_SETTLE_CAP
    if job.artifacts_phase in (None, ArtifactsPhase.PENDING) and job.finished_at is not None:
        return now < job.finished_at + UPLOAD_START_WAIT
    return False


__all__ = ["UPLOAD_SETTLE_CAP", "UPLOAD_START_WAIT", "outputs_prefix", "upload_pending"]
