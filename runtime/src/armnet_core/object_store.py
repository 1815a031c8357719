"""The object store that keeps job outputs: its settings from the environment, and its S3 client.

The node agent uploads each ended job's output directory there (docs/outputs.md); the
operator removes a job's outputs with the job at its TTL. Both read the same variables
(the chart sets them from ``artifacts.*`` and the Secret ``artifacts.credentialsSecret``)
and talk to the store through the same client settings: any S3-compatible server
(SeaweedFS in the test bed and ``armnet dev up``, AWS S3, an operator's own), path-style
addressing, and checksums only where S3 requires them (boto3 >= 1.36 adds CRC checksums
to every upload by default, which some compatible servers refuse).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from armnet_core.api import (
    ARTIFACTS_ACCESS_KEY_ENV,
    ARTIFACTS_BUCKET_ENV,
    ARTIFACTS_ENDPOINT_ENV,
    ARTIFACTS_REGION_ENV,
    ARTIFACTS_SECRET_KEY_ENV,
)


class StoreSettingsError(ValueError):
    """The store's variables are set only in part: a person must fix the deployment."""


@dataclass(frozen=True)
class StoreConfig:
    """Where job outputs are stored. ``endpoint_url`` None is AWS S3 itself."""

    bucket: str
    access_key_id: str
    secret_access_key: str
    endpoint_url: str | None = None
    region: str = "us-east-1"

    def __repr__(self) -> str:  # never the secret in a log line
        return f"StoreConfig(bucket={self.bucket!r}, endpoint_url={self.endpoint_url!r}, region={self.region!r})"

    @property
    def location(self) -> str:
        return f"s3://{self.bucket}/"

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> StoreConfig | None:
        """The settings from the process's env; None when no bucket is set (no store)."""
        env = os.environ if environ is None else environ
        bucket = env.get(ARTIFACTS_BUCKET_ENV, "").strip()
        if not bucket:
            return None
        missing = [name for name in (ARTIFACTS_ACCESS_KEY_ENV, ARTIFACTS_SECRET_KEY_ENV) if not env.get(name)]
        if missing:
            raise StoreSettingsError(
                f"{ARTIFACTS_BUCKET_ENV} is set but {', '.join(missing)} is not: give the process the store's keys "
                "(the chart reads them from the Secret named by artifacts.credentialsSecret)"
            )
        return cls(
            bucket=bucket, access_key_id=env[ARTIFACTS_ACCESS_KEY_ENV], secret_access_key=env[ARTIFACTS_SECRET_KEY_ENV],
            endpoint_url=env.get(ARTIFACTS_ENDPOINT_ENV) or None, region=env.get(ARTIFACTS_REGION_ENV) or "us-east-1",
        )


def s3_client(config: StoreConfig, *, max_attempts: int = 5, connect_timeout: float = 10,
              read_timeout: float = 60) -> Any:
    """A boto3 S3 client for ``config`` (imported here: only the processes that store need boto3)."""
    import boto3
    from botocore.config import Config

    return boto3.client(
        "s3",
        endpoint_url=config.endpoint_url,
        region_name=config.region,
        aws_access_key_id=config.access_key_id,
        aws_secret_access_key=config.secret_access_key,
        config=Config(
            s3={"addressing_style": "path"},
            retries={"mode": "standard", "max_attempts": max_attempts},
            request_checksum_calculation="when_required",
            response_checksum_validation="when_required",
            connect_timeout=connect_timeout,
            read_timeout=read_timeout,
        ),
    )


__all__ = ["StoreConfig", "StoreSettingsError", "s3_client"]

