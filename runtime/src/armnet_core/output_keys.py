"""Where a job's stored output lives in the bucket: plain names and checks, no store client.

The node agent writes ``<namespace>/<job uid>/files/...`` and, last, the manifest; the
operator removes the prefix with the job; the client and the FMS read it back
(docs/outputs.md). All of them take the layout from here.
"""

from __future__ import annotations

import re

#: The manifest the node agent writes last below a job's prefix: the stored files, their sizes and checksums.
MANIFEST_NAME = "manifest.json"
#: A manifest larger than this is not read (10,000 files of long names are ~3 MB).
MAX_MANIFEST_BYTES = 32 * 1024 * 1024

_NAMESPACE = re.compile(r"^[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?$")
_UID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9-]{0,127}$")


def job_prefix(namespace: str, job_uid: str) -> str:
    """Where a job's output is stored in the bucket, ``<namespace>/<job uid>/``; a namespace or uid outside
    Kubernetes' syntax is a ValueError (a prefix built from them never reaches another's objects)."""
    if not _NAMESPACE.match(namespace):
        raise ValueError(f"{namespace!r} is not a Kubernetes namespace name")
    if not _UID.match(job_uid):
        raise ValueError(f"{job_uid!r} is not a Kubernetes uid")
    return f"{namespace}/{job_uid}/"


def split_s3_location(location: str) -> tuple[str, str] | None:
    """``s3://bucket/key`` (a ``status.artifacts`` location or manifest) -> (bucket, key); None when it is not one."""
    if not location.startswith("s3://"):
        return None
    bucket, slash, key = location[5:].partition("/")
    return (bucket, key) if bucket and slash else None
