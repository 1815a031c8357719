"""A job's stored output, fetched back: the manifest the node agent wrote, then every file it lists.

The node agent stores an ended job's output directory under
``s3://<bucket>/<namespace>/<job uid>/`` with a ``manifest.json`` written last
(docs/outputs.md); the job's ``status.artifacts`` says where. This module reads
that manifest and downloads the files it lists with the user's own S3
credentials (boto3's usual chain: ``AWS_ACCESS_KEY_ID``/``AWS_SECRET_ACCESS_KEY``,
``~/.aws``), checking each file's SHA-256 before it is kept.

Nothing in the manifest is trusted for where a file goes: the names come from a
tenant's job. A name that is absolute, has an empty, ``.`` or ``..`` segment, or
would leave the download directory is refused, and a file whose bytes do not
match its checksum is not written.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Optional

from armnet_core.api import ARTIFACTS_ENDPOINT_ENV, ARTIFACTS_REGION_ENV
from armnet_core.output_keys import MAX_MANIFEST_BYTES, split_s3_location

from .errors import ClientError

logger = logging.getLogger(__name__)

CHUNK = 1 << 20


class ArtifactsError(ClientError):
    """The job's output cannot be read back; the message says why and what to do."""


@dataclass(frozen=True)
class StoredFile:
    """One file the manifest lists: where it goes below the download directory, its key and checksum."""

    path: str
    key: str
    bytes: int
    sha256: str


@dataclass(frozen=True)
class Manifest:
    files: tuple[StoredFile, ...]
    complete: bool
    left_out: tuple[tuple[str, str], ...]


def split_location(location: str) -> tuple[str, str]:
    """``s3://bucket/prefix/`` -> (bucket, prefix)."""
    split = split_s3_location(location)
    if split is None:
        raise ArtifactsError(f"status.artifacts.location {location[:200]!r} is not an s3://bucket/prefix/ address")
    return split


def safe_relative(name: str) -> PurePosixPath:
    """``name`` as a relative path that stays below the download directory, or :class:`ArtifactsError`."""
    path = PurePosixPath(name)
    parts = name.split("/")
    if not name or path.is_absolute() or any(part in ("", ".", "..") for part in parts) or "\x00" in name:
        raise ArtifactsError(f"the manifest names {name[:200]!r}, which is not a plain relative path; not downloaded")
    return path


def parse_manifest(data: bytes) -> Manifest:
    """The manifest's document; :class:`ArtifactsError` for anything but the agent's shape."""
    try:
        document = json.loads(data)
        files = tuple(
            StoredFile(str(f["path"]), str(f["key"]), int(f["bytes"]), str(f["sha256"])) for f in document["files"]
        )
        left = tuple((str(r["path"]), str(r["reason"])) for key in ("changed", "refused")
                     for r in document.get(key, ()))
        return Manifest(files, document.get("complete") is not False, left)
    except (ValueError, KeyError, TypeError) as exc:
        raise ArtifactsError(f"the output's manifest.json cannot be read ({exc}); was it written by the node agent?") \
            from exc


class OutputStore:
    """The bucket of a job's output, read with the user's credentials."""

    def __init__(self, bucket: str, *, endpoint_url: Optional[str] = None, region: Optional[str] = None,
                 environ: Optional[Mapping[str, str]] = None) -> None:
        try:
            import boto3
            from botocore.config import Config
        except ImportError as exc:  # pragma: no cover - the client extra brings it
            raise ArtifactsError("reading job outputs needs boto3: pip install 'armnet-runtime[client]'") from exc
        env = os.environ if environ is None else environ
        self.bucket = bucket
        self.endpoint_url = endpoint_url or env.get(ARTIFACTS_ENDPOINT_ENV) or None
        # A session of its own: boto3's default one keeps the first credentials it found for the process.
        self._s3: Any = boto3.session.Session().client(
            "s3", endpoint_url=self.endpoint_url,
            region_name=region or env.get(ARTIFACTS_REGION_ENV) or env.get("AWS_DEFAULT_REGION") or "us-east-1",
            config=Config(s3={"addressing_style": "path"}, retries={"mode": "standard", "max_attempts": 3},
                          request_checksum_calculation="when_required",
                          response_checksum_validation="when_required"),
        )

    def read(self, key: str, limit: int) -> bytes:
        body = self._get(key)["Body"]
        data = bytes(body.read(limit + 1))
        if len(data) > limit:
            raise ArtifactsError(f"s3://{self.bucket}/{key} is larger than {limit} bytes; not read")
        return data

    def chunks(self, key: str) -> Iterator[bytes]:
        body = self._get(key)["Body"]
        while chunk := body.read(CHUNK):
            yield bytes(chunk)

    def _get(self, key: str) -> Any:
        try:
            return self._s3.get_object(Bucket=self.bucket, Key=key)
        except Exception as exc:  # noqa: BLE001 - botocore's errors, told as what to do
            code = str((getattr(exc, "response", None) or {}).get("Error", {}).get("Code", "")) or type(exc).__name__
            where = f"s3://{self.bucket}/{key} at {self.endpoint_url or 'AWS S3'}"
            if code in ("AccessDenied", "InvalidAccessKeyId", "SignatureDoesNotMatch", "NoCredentialsError"):
                raise ArtifactsError(
                    f"the object store refused to read {where} ({code}): give your read credentials "
                    "(AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY) and the store's URL (--endpoint or "
                    f"${ARTIFACTS_ENDPOINT_ENV})") from exc
            if code in ("NoSuchKey", "404", "NoSuchBucket"):
                raise ArtifactsError(f"{where} does not exist ({code}): the output was removed, or this is "
                                     "another store (--endpoint)") from exc
            raise ArtifactsError(f"could not read {where}: {code}: {str(exc)[:300]}") from exc


def open_manifest(location: str, manifest: str, *, endpoint_url: Optional[str] = None) -> tuple[OutputStore, Manifest]:
    """The store of a job's stored output (``status.artifacts``' ``location`` and ``manifest``) and its manifest."""
    bucket, _ = split_location(location)
    manifest_bucket, manifest_key = split_location(manifest)
    store = OutputStore(manifest_bucket, endpoint_url=endpoint_url)
    if bucket != manifest_bucket:
        logger.warning("the manifest is in bucket %s, the output in %s", manifest_bucket, bucket)
    return store, parse_manifest(store.read(manifest_key, MAX_MANIFEST_BYTES))


@dataclass(frozen=True)
class Downloaded:
    written: tuple[str, ...]
    unchanged: tuple[str, ...]


def download(store: OutputStore, manifest: Manifest, destination: Path) -> Downloaded:
    """Every file of ``manifest`` below ``destination``, each checked against its SHA-256 before it is kept.

    A file already there with the same checksum is left as it is; a file whose bytes do not
    match raises :class:`ArtifactsError` after the files before it were kept (run it again
    to resume).
    """
    destination.mkdir(parents=True, exist_ok=True)
    root = destination.resolve()
    written, unchanged = [], []
    for stored in manifest.files:
        target = root.joinpath(*safe_relative(stored.path).parts)
        if not target.resolve().is_relative_to(root):  # a directory symlinked out, already in the destination
            raise ArtifactsError(f"{stored.path} would be written outside {destination}; not downloaded")
        if target.is_file() and _sha256_of(target) == stored.sha256:
            unchanged.append(stored.path)
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        with tempfile.NamedTemporaryFile(dir=target.parent, prefix=".armnet-", delete=False) as part:
            try:
                for chunk in store.chunks(stored.key):
                    digest.update(chunk)
                    part.write(chunk)
            except BaseException:
                Path(part.name).unlink(missing_ok=True)
                raise
        if digest.hexdigest() != stored.sha256:
            Path(part.name).unlink(missing_ok=True)
            raise ArtifactsError(
                f"{stored.path}: the stored bytes do not match the manifest's SHA-256 "
                f"({digest.hexdigest()[:16]}... != {stored.sha256[:16]}...); not written. The object was changed "
                "after the upload: tell the cluster's operator")
        try:
            os.chmod(part.name, 0o666 & ~_umask())  # as an ordinary new file, not mkstemp's 0600
            os.replace(part.name, target)
        except OSError:
            Path(part.name).unlink(missing_ok=True)
            raise
        written.append(stored.path)
    return Downloaded(tuple(written), tuple(unchanged))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as file:
        while chunk := file.read(CHUNK):
            digest.update(chunk)
    return digest.hexdigest()
