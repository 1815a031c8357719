"""What the client returns for a job run on a cluster: the seed's ``JobResult``, and where its output went.

``JobResult`` is the SDK's model with the seed's fields exactly (a local run has no object
store). A cluster's node agent also stores the job's output directory after the job ended
(docs/outputs.md): ``ClusterJobResult`` is a ``JobResult`` that says where
(``artifacts``: the RobotJob's ``status.artifacts``, the same model every reader of the
RobotJob uses), returned by ``wait()`` and ``execute()`` and kept in ``Job.result``.
"""

from __future__ import annotations

from typing import Optional

from armnet_core.models import JobResult
from armnet_core.resources import JobArtifacts
from pydantic import Field


class ClusterJobResult(JobResult):
    """A ``JobResult`` read from a RobotJob: the seed's fields, and ``artifacts`` from its ``status.artifacts``.

    ``artifacts.phase`` is ``Uploaded`` once the output is stored (``location``, ``manifest``,
    ``files``, ``bytes``; ``complete`` false: a file changed while it was sent), ``Pending``,
    ``Uploading`` or ``Retrying`` while the agent is still at it, ``Failed`` or ``Discarded``
    (``message`` says why) when nothing of the job's was stored.
    """

    artifacts: Optional[JobArtifacts] = Field(
        default=None, description="Where the job's output directory went; None when the agent wrote nothing about it."
    )


__all__ = ["ClusterJobResult"]
