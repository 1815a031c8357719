"""A real S3-compatible object store: SeaweedFS's ``weed server -s3`` on free loopback ports.

One process runs a master, a volume server, a filer and the S3 gateway, each on its own
free port (HTTP and gRPC chosen explicitly: SeaweedFS would otherwise take HTTP + 10000),
with its data in a temporary directory and one S3 identity (access and secret key,
admin on every bucket) from a config file. Telemetry, Iceberg and Lance endpoints are
off, so nothing leaves loopback. ``weed`` is built by scripts/setup.d/37-seaweedfs.sh.

``readers`` adds a tenant's read-only identity per namespace: it may read the objects
under ``<bucket>/<namespace>/`` and nothing else (no listing, no writes), which is how a
cluster hands each tenant keys to its own job outputs (docs/outputs.md, "Tenants' keys").
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.procs import ManagedProcess, free_port, progress, require_tool, wait_until

SEAWEEDFS_CACHE = Path(os.environ.get("ARMNET_SEAWEEDFS_DIR", Path.home() / ".cache/armnet/seaweedfs"))
ACCESS_KEY = "armnet-testbed"
#: The bucket the readiness check writes to (tests use buckets of their own).
READY_BUCKET = "armnet-testbed-ready"
#: A cold start on a loaded 2-core machine (master election, first volume) takes a while.
START_TIMEOUT_S = 120


def weed_binary() -> Path:
    """``~/.cache/armnet/seaweedfs/<version>/bin/weed`` of the version setup built last."""
    override = os.environ.get("ARMNET_WEED")
    if override:
        return Path(override)
    current = SEAWEEDFS_CACHE / "current"
    if not current.is_file():
        raise TestbedSetupError(f"no SeaweedFS built yet ({current} is missing): run scripts/setup.sh")
    return SEAWEEDFS_CACHE / current.read_text().strip() / "bin" / "weed"


#: A bucket and namespace as Kubernetes and S3 spell them: a grant built from them has no wildcard.
_BUCKET = re.compile(r"^[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]$")
_NAMESPACE = re.compile(r"^[a-z0-9]([-a-z0-9]{0,61}[a-z0-9])?$")


@dataclass(frozen=True)
class Reader:
    """A tenant's read-only keys: the objects under ``<bucket>/<namespace>/``, nothing else."""

    name: str
    bucket: str
    namespace: str
    access_key: str
    secret_key: str

    @property
    def action(self) -> str:
        """SeaweedFS's grant: ``Read`` on every key below the namespace's prefix (the agent's layout), or
        on the whole bucket when the namespace is empty (the FMS's keys)."""
        return f"Read:{self.bucket}/{self.namespace}/*" if self.namespace else f"Read:{self.bucket}"

    def env(self) -> dict[str, str]:
        """What the tenant exports for ``armnet artifacts`` (boto3's credential chain)."""
        return {"AWS_ACCESS_KEY_ID": self.access_key, "AWS_SECRET_ACCESS_KEY": self.secret_key}


class SeaweedS3:
    """SeaweedFS with its S3 gateway; ``endpoint`` is ``http://127.0.0.1:<port>``.

    ``readers`` maps a reader's name to the (bucket, namespace) whose outputs it may read (namespace
    ``""``: the whole bucket).
    """

    def __init__(self, workdir: Path | None = None, readers: Mapping[str, tuple[str, str]] | None = None) -> None:
        self._owns_workdir = workdir is None
        self.workdir = workdir or Path(tempfile.mkdtemp(prefix="armnet-s3-"))
        self.s3_port = free_port()
        self.endpoint = f"http://127.0.0.1:{self.s3_port}"
        self.access_key = ACCESS_KEY
        self.secret_key = secrets.token_hex(20)
        self.region = "us-east-1"
        self.data_dir = self.workdir / "data"
        self._ports = {name: free_port() for name in (
            "master.port", "master.port.grpc", "volume.port", "volume.port.grpc",
            "filer.port", "filer.port.grpc", "s3.port.grpc",
        )}
        self._proc: ManagedProcess | None = None
        self.readers: dict[str, Reader] = {}
        for name, (bucket, namespace) in (readers or {}).items():
            if not (_BUCKET.match(bucket) and (namespace == "" or _NAMESPACE.match(namespace))):
                raise ValueError(f"reader {name!r}: {bucket!r}/{namespace!r} is not a bucket and a namespace")
            self.readers[name] = Reader(name, bucket, namespace, f"reader-{secrets.token_hex(8)}",
                                        secrets.token_hex(20))

    def start(self) -> SeaweedS3:
        binary = require_tool("weed", weed_binary())
        self.data_dir.mkdir(parents=True, exist_ok=True)
        config = self.workdir / "s3.json"
        config.write_text(json.dumps({"identities": [{
            "name": "armnet-testbed",
            "credentials": [{"accessKey": self.access_key, "secretKey": self.secret_key}],
            "actions": ["Admin", "Read", "List", "Tagging", "Write"],
        }, *({
            "name": reader.name,
            "credentials": [{"accessKey": reader.access_key, "secretKey": reader.secret_key}],
            "actions": [reader.action],
        } for reader in self.readers.values())]}))
        config.chmod(0o600)
        # SeaweedFS makes each bucket a collection and gives a new collection 7 volumes at its
        # first write (master.toml's copy_1); with -volume.max=32 the fifth bucket's first write
        # failed with InternalError ("no free volumes left"). One volume per bucket is plenty
        # here (volumes are sparse files of at most 64 MB); the master reads master.toml from
        # its working directory.
        (self.workdir / "master.toml").write_text("[master.volume_growth]\ncopy_1 = 1\n")
        started = time.monotonic()
        argv = [
            binary, "server", f"-dir={self.data_dir}", "-ip=127.0.0.1", "-ip.bind=127.0.0.1",
            "-filer", "-s3", f"-s3.port={self.s3_port}", f"-s3.config={config}",
            "-s3.port.iceberg=0", "-s3.port.lance=0", "-master.telemetry=false",
            "-master.volumeSizeLimitMB=64", "-volume.max=100", "-volume.preStopSeconds=0",
            f"-filer.localSocket={self.workdir / 'filer.sock'}", f"-s3.localSocket={self.workdir / 's3.sock'}",
            *(f"-{name}={port}" for name, port in self._ports.items()),
        ]
        self._proc = ManagedProcess("weed-server", argv, self.workdir / "weed.log", cwd=self.workdir)
        proc = self._proc
        wait_until(self._serves_s3, timeout=START_TIMEOUT_S, what=f"SeaweedFS S3 on {self.endpoint}",
                   interval=0.5, alive=proc.ensure_running)
        # The gateway answers before the master has a writable volume: ready once a write lands.
        wait_until(self._accepts_writes, timeout=START_TIMEOUT_S, what=f"a first write to {self.endpoint}",
                   interval=0.5, alive=proc.ensure_running)
        progress(f"SeaweedFS S3 ready at {self.endpoint} in {time.monotonic() - started:.1f} s")
        return self

    def _serves_s3(self) -> bool:
        # An unsigned ListBuckets: the gateway answers 403 (AccessDenied) once it serves requests.
        try:
            with urllib.request.urlopen(self.endpoint + "/", timeout=2):
                return True
        except urllib.error.HTTPError as exc:
            return exc.code in (403, 200)
        except (urllib.error.URLError, TimeoutError):
            return False

    def client(self, reader: str | None = None) -> Any:
        """A boto3 S3 client with the admin's keys, or ``reader``'s (path-style, as the agent's)."""
        import boto3
        from botocore.config import Config

        keys = self.readers[reader] if reader is not None else None
        return boto3.client(
            "s3", endpoint_url=self.endpoint, region_name=self.region,
            aws_access_key_id=keys.access_key if keys else self.access_key,
            aws_secret_access_key=keys.secret_key if keys else self.secret_key,
            config=Config(s3={"addressing_style": "path"}, retries={"mode": "standard", "max_attempts": 1},
                          request_checksum_calculation="when_required",
                          response_checksum_validation="when_required"),
        )

    def reader_env(self, reader: str) -> dict[str, str]:
        """A service's env for reading job outputs with ``reader``'s keys (the FMS's, say)."""
        from armnet_core import api

        keys = self.readers[reader]
        return {**self.agent_env(keys.bucket), api.ARTIFACTS_ACCESS_KEY_ENV: keys.access_key,
                api.ARTIFACTS_SECRET_KEY_ENV: keys.secret_key}

    def agent_env(self, bucket: str) -> dict[str, str]:
        """The node agent's env for storing job outputs in ``bucket`` here (docs/outputs.md)."""
        from armnet_core import api

        return {api.ARTIFACTS_ENDPOINT_ENV: self.endpoint, api.ARTIFACTS_BUCKET_ENV: bucket,
                api.ARTIFACTS_REGION_ENV: self.region, api.ARTIFACTS_ACCESS_KEY_ENV: self.access_key,
                api.ARTIFACTS_SECRET_KEY_ENV: self.secret_key}

    def objects(self, bucket: str, prefix: str = "") -> dict[str, bytes]:
        """Every object under ``prefix`` in ``bucket``, read back whole: what a test checks the store holds."""
        s3 = self.client()
        keys = [item["Key"] for page in s3.get_paginator("list_objects_v2").paginate(Bucket=bucket, Prefix=prefix)
                for item in page.get("Contents", ())]
        return {key: s3.get_object(Bucket=bucket, Key=key)["Body"].read() for key in keys}

    def create_bucket(self, name: str) -> str:
        self.client().create_bucket(Bucket=name)
        return name

    def _accepts_writes(self) -> bool:
        from botocore.exceptions import BotoCoreError, ClientError

        s3 = self.client()
        try:
            try:
                s3.create_bucket(Bucket=READY_BUCKET)
            except ClientError as exc:
                if exc.response.get("Error", {}).get("Code") not in ("BucketAlreadyOwnedByYou", "BucketAlreadyExists"):
                    raise
            s3.put_object(Bucket=READY_BUCKET, Key="ready", Body=b"ready")
            return bool(s3.get_object(Bucket=READY_BUCKET, Key="ready")["Body"].read() == b"ready")
        except (BotoCoreError, ClientError):
            return False

    def stop(self) -> None:
        if self._proc is not None:
            # weed's graceful exit takes ~15 s (measured); its data is a temporary directory removed
            # below, so after 2 s it is killed: every session that uses the store ends 13 s sooner.
            self._proc.stop(timeout=2)
            self._proc = None
        if self._owns_workdir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> SeaweedS3:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
