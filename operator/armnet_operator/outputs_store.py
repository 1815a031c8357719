"""The object store of job outputs, as the operator uses it: remove one finished job's prefix.

The node agent stores the outputs (``armnet_node.artifacts``); the operator removes a job's
with the job at its TTL (``artifact_removal`` decides which prefix). The settings and the
client are the agent's (``armnet_core.object_store``): the same variables, which the chart
sets on both from ``artifacts.*``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from armnet_core.backoff import BackoffPolicy
from armnet_core.object_store import StoreConfig, StoreSettingsError, s3_client

from .errors import PermanentError, StoreError

#: A removal runs inside the reconcile pass, before its bindings: a store that does not answer
#: must cost a pass seconds, not minutes. After a failure the store is not asked again for a while
#: (doubling from ``RETRY.first_s`` to ``RETRY.max_s``): its jobs wait, the rest of the pass does not.
CONNECT_TIMEOUT_S = 2.0
READ_TIMEOUT_S = 5.0
RETRY = BackoffPolicy(first_s=10.0, max_s=300.0)


class OutputsStore:
    def __init__(self, config: StoreConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.bucket = config.bucket
        self._s3: Any = s3_client(config, max_attempts=1, connect_timeout=CONNECT_TIMEOUT_S,
                                  read_timeout=READ_TIMEOUT_S)
        self._clock = clock
        self._backoff = RETRY.start()
        self._resting_until = 0.0
        self._last_error = ""

    @classmethod
    def from_env(cls) -> OutputsStore | None:
        """The store the environment names; None without one (outputs are then never removed)."""
        try:
            config = StoreConfig.from_env()
        except StoreSettingsError as error:
            raise PermanentError(str(error)) from error
        return None if config is None else cls(config)

    def remove(self, prefix: str) -> int:
        """Remove every object under ``prefix`` (a page of up to 1,000 a request); how many.

        Right after a failure the store is not asked: StoreError says when it will be again.
        """
        now = self._clock()
        if now < self._resting_until:
            raise StoreError(f"{self._last_error}; not asked again for {self._resting_until - now:.0f} s")
        try:
            removed = self._remove(prefix)
        except StoreError as error:
            self._last_error = str(error)
            self._resting_until = self._clock() + self._backoff.failed()
            raise
        self._backoff.succeeded()
        return removed

    def _remove(self, prefix: str) -> int:
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
