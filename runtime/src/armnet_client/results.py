"""What the client returns for a job run on a cluster: the seed's ``JobResult``, and where its output went.

``JobResult`` is the SDK's model with the seed's fields exactly (a local run has no object
store). A cluster's node agent also stores the job's output directory after the job ended
(docs/outputs.md): ``ClusterJobResult`` is a ``JobResult`` that says where
(``artifacts``), returned by ``wait()`` and ``execute()`` and kept in ``Job.result``.
"""

from __future__ import annotations

from typing import Optional

from armnet_core.models import JobResult
from pydantic import BaseModel, Field


class Artifacts(BaseModel):
    """Where the job's output directory (``ARMNET_OUTPUT_DIR``) went: ``status.artifacts`` of its RobotJob.

    The node agent stores it in the cluster's object store after the job ended
    (docs/outputs.md); ``armnet artifacts JOB --download DIR`` fetches it. ``phase`` is
    ``Uploaded`` when it is stored (``complete`` false: a file changed while it was sent),
    ``Pending``, ``Uploading`` or ``Retrying`` while the agent is still at it, ``Failed`` or
    ``Discarded`` (with ``message`` saying why) when nothing was stored.
    """

    phase: str = Field(..., description="Pending, Uploading, Uploaded, Retrying, Failed or Discarded.")
    location: Optional[str] = Field(default=None, description="s3://<bucket>/<namespace>/<job uid>/")
    manifest: Optional[str] = Field(default=None, description="The stored manifest: every file with its SHA-256.")
    files: Optional[int] = Field(default=None, description="Files stored.")
    bytes: Optional[int] = Field(default=None, description="Bytes stored.")
    complete: Optional[bool] = Field(default=None, description="False when a file was left out.")
    left_out: Optional[int] = Field(default=None, description="Entries not stored (the message names why).")
    message: Optional[str] = Field(default=None, description="Why anything was left out, or nothing stored.")


class ClusterJobResult(JobResult):
    """A ``JobResult`` read from a RobotJob: the seed's fields, and ``artifacts`` from its ``status.artifacts``."""

    artifacts: Optional[Artifacts] = Field(
        default=None, description="Where the job's output directory went; None when the agent wrote nothing about it."
    )


__all__ = ["Artifacts", "ClusterJobResult"]
