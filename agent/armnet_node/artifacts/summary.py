"""``status.artifacts``: what a job's user reads about its output, from an upload's outcome (pure).

A summary, never the file list: a dataset of 10,000 files would not fit an object
(etcd's 1.5 MB) and the manifest in the store already lists every file with its
checksum. The summary says where the output is, how much of it, whether it is whole,
and why anything was left out, in the words a user acts on.
"""

from __future__ import annotations

from typing import Any

from armnet_core.api import ArtifactsPhase

from armnet_node.artifacts.model import UploadReport

#: ``status.artifacts.phase`` values (the CRD's enum, declared in ``armnet_core.api``).
PENDING = ArtifactsPhase.PENDING
UPLOADING = ArtifactsPhase.UPLOADING
UPLOADED = ArtifactsPhase.UPLOADED
RETRYING = ArtifactsPhase.RETRYING
FAILED = ArtifactsPhase.FAILED
DISCARDED = ArtifactsPhase.DISCARDED

#: How many left-out entries the message names (the manifest lists up to its own cap).
NAMED_IN_MESSAGE = 3
#: The CRD's maxLength of ``message``; longer messages are cut with an ellipsis.
MESSAGE_MAX = 1024

DISCARDED_MESSAGE = (
    "this cluster has no object store for job outputs, so what the job wrote to ARMNET_OUTPUT_DIR was "
    "removed with the job; ask the cluster's operator to set the chart's artifacts.bucket"
)


def location(bucket: str, prefix: str) -> str:
    return f"s3://{bucket}/{prefix}"


def pending() -> dict[str, Any]:
    """Written with the terminal status: the output waits in the upload queue (a final phase follows)."""
    return {"phase": PENDING}


def uploading(bucket: str, prefix: str) -> dict[str, Any]:
    return {"phase": UPLOADING, "location": location(bucket, prefix)}


def uploaded(report: UploadReport) -> dict[str, Any]:
    """The summary of a finished upload; ``complete`` false when a file changed while it was sent."""
    left_out = [*report.changed, *report.refused]
    summary: dict[str, Any] = {
        "phase": UPLOADED,
        "location": location(report.bucket, report.prefix),
        "manifest": f"s3://{report.bucket}/{report.manifest_key}",
        "files": len(report.artifacts),
        "bytes": report.total_bytes,
        "complete": report.complete,
        "leftOut": len(left_out),
    }
    if left_out:
        named = "; ".join(f"{entry.path}: {entry.reason}" for entry in left_out[:NAMED_IN_MESSAGE])
        more = f" (and {len(left_out) - NAMED_IN_MESSAGE} more: see the manifest)" if len(left_out) > NAMED_IN_MESSAGE else ""
        summary["message"] = _cut(f"{len(left_out)} entries were not stored: {named}{more}")
    return summary


def retrying(bucket: str, prefix: str, error: str) -> dict[str, Any]:
    """The store refused or did not answer: the output waits on the robot host and is tried again."""
    return {"phase": RETRYING, "location": location(bucket, prefix),
            "message": _cut(f"{error}; the output is kept on the robot host and the upload is retried")}


def failed(error: str, location: str | None = None) -> dict[str, Any]:
    """Nothing of the job's output stored; ``location``: where the cell's record of the job was (it goes at the TTL)."""
    return {"phase": FAILED, "message": _cut(error), **({"location": location} if location else {})}


def discarded() -> dict[str, Any]:
    return {"phase": DISCARDED, "message": DISCARDED_MESSAGE}


def _cut(text: str) -> str:
    return text if len(text) <= MESSAGE_MAX else text[: MESSAGE_MAX - 1] + "…"
