"""What one upload is made of and what it reports; the package's errors."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: Default cap on the entries (files, directories, links) the walk visits in one output directory.
DEFAULT_MAX_FILES = 10_000
#: Default cap on the bytes of one job's output.
DEFAULT_MAX_BYTES = 10 * 1024**3


class ArtifactError(Exception):
    """Something kept a job's output from the object store; the message says what to do."""


class OutputTooLarge(ArtifactError):
    """Permanent: the output directory holds more entries or bytes than the cap; nothing was uploaded."""


class StoreMisconfigured(ArtifactError):
    """Permanent until an operator fixes the agent's settings: no bucket, wrong keys, access denied."""


class StoreUnavailable(ArtifactError):
    """Transient: the store did not answer or failed; the upload may be run again and resumes."""


@dataclass(frozen=True)
class OutputLimits:
    """Bounds on one job's output: a tenant's directory must not exhaust the agent or the store."""

    max_files: int = DEFAULT_MAX_FILES
    max_bytes: int = DEFAULT_MAX_BYTES


@dataclass(frozen=True)
class LocalFile:
    """One regular file to upload, as the walk saw it.

    ``source`` is what is opened: the file itself, or the target of a symbolic link that
    stays inside the directory. ``size`` and ``mtime_ns`` tell a file that changed since.
    """

    path: str
    source: Path
    size: int
    mtime_ns: int


@dataclass(frozen=True)
class Refused:
    """An entry left out, with the reason (a link out of the directory, a bad name, a changed file)."""

    path: str
    reason: str


@dataclass(frozen=True)
class Scan:
    """The output directory as the walk found it: the files to upload and the entries left out."""

    files: tuple[LocalFile, ...]
    refused: tuple[Refused, ...]

    @property
    def total_bytes(self) -> int:
        return sum(f.size for f in self.files)


@dataclass(frozen=True)
class Artifact:
    """One stored file: its path in the output directory, its object key, size and SHA-256 (hex)."""

    path: str
    key: str
    bytes: int
    sha256: str


@dataclass(frozen=True)
class UploadReport:
    """The outcome of one upload: what is stored (whole), what was left out, and where."""

    bucket: str
    prefix: str
    manifest_key: str
    artifacts: tuple[Artifact, ...]
    refused: tuple[Refused, ...]
    #: Files that changed while they were read or uploaded: not stored (a half-written file is never reported whole).
    changed: tuple[Refused, ...]
    #: Bytes sent in this run (files already stored with the same checksum are not sent again).
    uploaded_bytes: int
    #: Files found already stored with the same checksum (a resumed upload).
    already_stored: int

    @property
    def complete(self) -> bool:
        """Every file the walk accepted is stored whole."""
        return not self.changed

    @property
    def total_bytes(self) -> int:
        return sum(a.bytes for a in self.artifacts)
