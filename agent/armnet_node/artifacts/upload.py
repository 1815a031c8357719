"""One job's upload: walk, hash, skip what is stored, upload the rest, write the manifest last.

Resumable by construction: every object is written whole (an S3 PUT, or a multipart
upload that completes, is atomic), carries its file's SHA-256, and a re-run skips an
object whose size and SHA-256 match. The manifest is written only after every file, so
its presence means the upload finished; an agent killed at any point runs the upload
again and neither loses a file nor stores one twice (keys are the files' paths).

A file that changes while it is read or sent (its size or modification time moves) is
not stored: the object is removed again and the file is reported as changed, so a
half-written file is never listed as whole.
"""

from __future__ import annotations

import hashlib
import os
import stat
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from armnet_core.output_keys import job_prefix

from armnet_node.artifacts.keys import (
    already_stored,
    build_manifest,
    files_prefix,
    manifest_key,
    object_key,
)
from armnet_node.artifacts.model import (
    Artifact,
    LocalFile,
    OutputLimits,
    Refused,
    Scan,
    UploadReport,
)
from armnet_node.artifacts.scan import scan_job_output
from armnet_node.artifacts.store import ObjectStore

HASH_CHUNK = 1 << 20


class FileChanged(Exception):
    """The file is not what the walk saw any more (written to, truncated, replaced)."""


def upload_output(
    root: Path | None, store: ObjectStore, namespace: str, job_uid: str, limits: OutputLimits | None = None,
    record: Path | None = None,
) -> UploadReport:
    """Upload the job's output directory ``root`` under ``<namespace>/<job uid>/`` in ``store``, and the cell's
    ``record`` of the job beside it (its paths under ``armnet-cell/``); ``root`` None: the record alone.

    Raises :class:`OutputTooLarge` (nothing uploaded), :class:`StoreMisconfigured` or
    :class:`StoreUnavailable` (run it again: it resumes).
    """
    prefix = job_prefix(namespace, job_uid)
    return upload_scan(scan_job_output(root, record, limits or OutputLimits(), prefix), store, namespace, job_uid)


def upload_scan(
    scan: Scan, store: ObjectStore, namespace: str, job_uid: str,
    on_stored: Callable[[Artifact], None] | None = None,
) -> UploadReport:
    """Upload the files of ``scan`` and write the manifest; ``on_stored`` is told of each stored file."""
    prefix = job_prefix(namespace, job_uid)
    stored_sizes = store.sizes(files_prefix(prefix))
    artifacts: list[Artifact] = []
    refused = list(scan.refused)
    changed: list[Refused] = []
    sent = 0
    skipped = 0
    for local in scan.files:
        key = object_key(prefix, local.path)
        try:
            with _opened_unchanged(local) as (body, stat_fd):
                sha256 = _sha256(body)
                _check_unchanged(stat_fd, local)
                if already_stored(local.size, sha256, stored_sizes.get(key),
                                  store.stored_sha256(key) if key in stored_sizes else None):
                    skipped += 1
                else:
                    body.seek(0)
                    store.put_file(key, body, sha256)
                    try:
                        _check_unchanged(stat_fd, local)
                    except FileChanged:
                        store.delete(key)  # never leave a half-written file behind a whole file's checksum
                        raise
                    sent += local.size
        except FileChanged as exc:
            changed.append(Refused(local.path, str(exc)))
            continue
        except OSError as exc:
            refused.append(Refused(local.path, f"cannot be read: {exc.strerror or exc}"))
            continue
        artifact = Artifact(local.path, key, local.size, sha256)
        artifacts.append(artifact)
        if on_stored is not None:
            on_stored(artifact)
    manifest = manifest_key(prefix)
    store.put_bytes(manifest, build_manifest(namespace, job_uid, artifacts, refused, changed))
    return UploadReport(
        bucket=store.bucket, prefix=prefix, manifest_key=manifest, artifacts=tuple(artifacts),
        refused=tuple(refused), changed=tuple(changed), uploaded_bytes=sent, already_stored=skipped,
    )


@contextmanager
def _opened_unchanged(local: LocalFile) -> Iterator[tuple[IO[bytes], int]]:
    """The file opened without following a link (a link swapped in since the walk fails) or blocking.

    Then it must still be the regular file of the walk's size and modification time. Yields
    the file and a second descriptor of it to check it by: boto3's upload closes the file
    object it is given, and the check after the upload must still reach the same file.
    """
    fd = os.open(local.source, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    stat_fd = os.dup(fd)
    try:
        with os.fdopen(fd, "rb") as body:
            if not stat.S_ISREG(os.fstat(stat_fd).st_mode):
                raise FileChanged("replaced by something other than a regular file since the directory was read")
            _check_unchanged(stat_fd, local)
            yield body, stat_fd
    finally:
        os.close(stat_fd)


def _check_unchanged(stat_fd: int, local: LocalFile) -> None:
    now = os.fstat(stat_fd)
    if now.st_size != local.size:
        raise FileChanged(
            f"changed while it was uploaded (its size went from {local.size} to {now.st_size} bytes): a process "
            "still wrote to it after the job ended; it was not stored"
        )
    if now.st_mtime_ns != local.mtime_ns:
        raise FileChanged(
            "changed while it was uploaded (it was written to after the job ended); it was not stored"
        )


def _sha256(body: IO[bytes]) -> str:
    digest = hashlib.sha256()
    while chunk := body.read(HASH_CHUNK):
        digest.update(chunk)
    return digest.hexdigest()
