"""A job's output directory, uploaded to an S3-compatible object store when the job ends.

- ``model``: what an upload is made of and reports (frozen dataclasses) and the errors.
- ``keys`` (pure): object keys under ``<namespace>/<job uid>/``, which names may become
  keys, whether a stored object is already the local file, and the manifest document.
- ``scan``: the walk of the output directory (bounded; no symlink out; nothing followed
  that could leave the directory).
- ``store``: the object store through boto3 (list, head, put, delete).
- ``upload``: one job's upload, resumable (a re-run skips what is stored with the same
  checksum; the manifest is written last).
- ``summary`` (pure): ``status.artifacts``, what the job's user reads about its output.

The package never reads the job's env, the Kubernetes API or the connector: the agent
hands it a directory, a job's identity and a store.
"""

from armnet_core.object_store import StoreConfig

from armnet_node.artifacts import summary
from armnet_node.artifacts.model import (
    Artifact,
    ArtifactError,
    OutputLimits,
    OutputTooLarge,
    Refused,
    StoreMisconfigured,
    StoreUnavailable,
    UploadReport,
)
from armnet_node.artifacts.store import ObjectStore
from armnet_node.artifacts.upload import upload_output

__all__ = [
    "Artifact",
    "ArtifactError",
    "ObjectStore",
    "OutputLimits",
    "OutputTooLarge",
    "Refused",
    "StoreConfig",
    "StoreMisconfigured",
    "StoreUnavailable",
    "UploadReport",
    "summary",
    "upload_output",
]
