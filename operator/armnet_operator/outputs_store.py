"""The object store of job outputs, as the operator uses it: remove one finished job's prefix.

The node agent stores the outputs (``armnet_node.artifacts``); the operator removes a job's
with the job at its TTL (``artifact_removal`` decides which prefix). The settings and the
client are the agent's (``armnet_core.object_store``): the same variables, which the chart
sets on both from ``artifacts.*``.
"""

from __future__ import annotations

from typing import Any

from armnet_core.object_store import StoreConfig, StoreSettingsError, s3_client

from .errors import PermanentError, StoreError


class OutputsStore:
    def __init__(self, config: StoreConfig) -> None:
        self.config = config
        self.bucket = config.bucket
        self._s3: Any = s3_client(config, max_attempts=3)

    @classmethod
    def from_env(cls) -> OutputsStore | None:
        """The store the environment names; None without one (outputs are then never removed)."""
        try:
            config = StoreConfig.from_env()
        except StoreSettingsError as error:
            raise PermanentError(str(error)) from error
        return None if config is None else cls(config)

    def remove(self, prefix: str) -> int:
        """Remove every object under ``prefix`` (a page of up to 1,000 a request); how many."""
        removed = 0
        try:
            pages = self._s3.get_paginator("list_objects_v2").paginate(Bucket=self.bucket, Prefix=prefix)
            for page in pages:
                keys = [{"Key": item["Key"]} for item in page.get("Contents", [])]
                if not keys:
                    continue
                answer = self._s3.delete_objects(Bucket=self.bucket, Delete={"Objects": keys, "Quiet": True})
                refused = answer.get("Errors") or []
                if refused:
                    first = refused[0]
                    raise StoreError(f"the object store refused to remove {len(refused)} object(s) under {prefix}, "
                                     f"e.g. {first.get('Key')}: {first.get('Code')} {first.get('Message')}")
                removed += len(keys)
        except StoreError:
            raise
        except Exception as error:  # noqa: BLE001 - botocore's errors: the next pass tries again
            raise StoreError(f"the object store at {self.config.endpoint_url or 'AWS S3'} did not remove "
                             f"{prefix} in bucket {self.bucket}: {type(error).__name__}: {error}") from error
        return removed


__all__ = ["OutputsStore"]
