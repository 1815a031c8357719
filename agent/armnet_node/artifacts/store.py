"""The object store, through boto3: the few S3 calls an upload needs, and their errors mapped.

The settings and the client are ``armnet_core.object_store``'s (the operator's too). The
file's SHA-256 travels in the object's metadata (``x-amz-meta-sha256``); that is what a
resumed upload compares, not the ETag (an MD5, or a digest of digests for a multipart upload).
"""

from __future__ import annotations

from typing import IO, Any

from armnet_core.api import ARTIFACTS_ACCESS_KEY_ENV, ARTIFACTS_BUCKET_ENV
from armnet_core.object_store import StoreConfig, s3_client

from armnet_node.artifacts.keys import SHA256_METADATA
from armnet_node.artifacts.model import StoreMisconfigured, StoreUnavailable

#: S3 error codes an operator must fix (a retry cannot help).
_MISCONFIGURED = frozenset({
    "AccessDenied", "InvalidAccessKeyId", "SignatureDoesNotMatch", "NoSuchBucket", "InvalidBucketName",
    "AllAccessDisabled", "AccountProblem",
})


class ObjectStore:
    """One bucket. Every method raises :class:`StoreMisconfigured` or :class:`StoreUnavailable`."""

    def __init__(self, config: StoreConfig, *, max_attempts: int = 5) -> None:
        self.config = config
        self.bucket = config.bucket
        self._s3: Any = s3_client(config, max_attempts=max_attempts)

    def ensure_bucket(self) -> None:
        """Create the bucket when absent (development stores; a production bucket is the operator's)."""
        try:
            self._s3.head_bucket(Bucket=self.bucket)
            return
        except Exception as exc:  # noqa: BLE001 - mapped below; a missing bucket is created
            if _code(exc) not in ("404", "NoSuchBucket", "NotFound"):
                raise self._mapped(exc, "check the bucket") from exc
        self._call("create the bucket", self._s3.create_bucket, Bucket=self.bucket)

    def sizes(self, prefix: str) -> dict[str, int]:
        """Key -> size of every object under ``prefix``."""
        found: dict[str, int] = {}
        pages = self._s3.get_paginator("list_objects_v2").paginate(Bucket=self.bucket, Prefix=prefix)
        try:
            for page in pages:
                for item in page.get("Contents", ()):
                    found[str(item["Key"])] = int(item["Size"])
        except Exception as exc:  # noqa: BLE001 - botocore's errors, mapped
            raise self._mapped(exc, f"list {prefix}") from exc
        return found

    def stored_sha256(self, key: str) -> str | None:
        """The SHA-256 in the object's metadata; None when the object or the entry is missing."""
        try:
            head = self._s3.head_object(Bucket=self.bucket, Key=key)
        except Exception as exc:  # noqa: BLE001 - botocore's errors, mapped
            if _code(exc) in ("404", "NoSuchKey", "NotFound"):
                return None
            raise self._mapped(exc, f"read {key}") from exc
        value = (head.get("Metadata") or {}).get(SHA256_METADATA)
        return str(value) if value else None

    def put_file(self, key: str, body: IO[bytes], sha256: str) -> None:
        """Upload an open file (multipart when large); its SHA-256 goes into the object's metadata."""
        self._call(f"upload {key}", self._s3.upload_fileobj, body, self.bucket, key,
                   ExtraArgs={"Metadata": {SHA256_METADATA: sha256}})

    def put_bytes(self, key: str, data: bytes, content_type: str = "application/json") -> None:
        self._call(f"upload {key}", self._s3.put_object, Bucket=self.bucket, Key=key, Body=data,
                   ContentType=content_type)

    def get_bytes(self, key: str) -> bytes:
        response = self._call(f"read {key}", self._s3.get_object, Bucket=self.bucket, Key=key)
        return bytes(response["Body"].read())

    def delete(self, key: str) -> None:
        self._call(f"delete {key}", self._s3.delete_object, Bucket=self.bucket, Key=key)

    def _call(self, what: str, method: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return method(*args, **kwargs)
        except Exception as exc:  # noqa: BLE001 - botocore's errors, mapped
            raise self._mapped(exc, what) from exc

    def _mapped(self, exc: Exception, what: str) -> Exception:
        where = f"{self.config.location} at {self.config.endpoint_url or 'AWS S3'}"
        code = _code(exc)
        if code in _MISCONFIGURED:
            return StoreMisconfigured(
                f"the object store {where} refused to {what}: {code}; check the agent's bucket and keys "
                f"({ARTIFACTS_BUCKET_ENV}, {ARTIFACTS_ACCESS_KEY_ENV})"
            )
        if not code and not _is_botocore(exc):
            return exc  # not the store's: an agent bug stays visible as itself
        return StoreUnavailable(f"the object store {where} failed to {what}: {code or type(exc).__name__}: {exc}")


def _code(exc: BaseException) -> str:
    """The S3 error code of ``exc`` or of the error it wraps (boto3's transfer errors wrap the client's)."""
    seen: BaseException | None = exc
    while seen is not None:
        response = getattr(seen, "response", None)
        if isinstance(response, dict):
            return str((response.get("Error") or {}).get("Code") or "")
        seen = seen.__cause__ or seen.__context__
    return ""


def _is_botocore(exc: Exception) -> bool:
    module = type(exc).__module__
    return module.startswith(("botocore", "boto3", "s3transfer", "urllib3"))
