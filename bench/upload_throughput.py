"""A job's output upload through the agent, against the same files put by the plain S3 client.

The agent's upload (``armnet_node.artifacts.upload_output``) does more than send bytes:
it walks the directory without following links, hashes every file (SHA-256, stored
with the object so a re-run skips it), checks each file did not change while it was
sent, and writes a manifest last. This measures what that costs against boto3's own
``upload_file`` of the same files to the same server in the same run (target: the
agent's throughput ≥ 0.8x the plain client's).

The server is SeaweedFS's S3 gateway on loopback (the test bed's, ``armnet_testbed.objstore``).
The directory is shaped like a recorded LeRobot dataset: a few large files (the
episodes' videos), some medium ones (the episodes' parquet), many small ones (metadata,
images). Each round uploads it once each way, alternating, under a fresh prefix, so
nothing is skipped as stored; the medians are compared.

Usage: ``~/.cache/armnet/venv/bin/python bench/upload_throughput.py [--rounds 3] [--large-mb 8]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for path in ("agent", "runtime/src", "testbed"):
    sys.path.insert(0, str(REPO / path))

from armnet_node.artifacts import ObjectStore, StoreConfig, upload_output  # noqa: E402
from armnet_testbed.objstore import SeaweedS3  # noqa: E402

TARGET = 0.8
BUCKET = "bench-uploads"


def make_output(root: Path, large: int, large_mb: int, medium: int, small: int) -> tuple[int, int]:
    """A dataset-shaped directory of random bytes (incompressible); (files, bytes)."""
    layout = [("videos", large, large_mb << 20, ".mp4"), ("data", medium, 256 << 10, ".parquet"),
              ("meta", small, 4 << 10, ".json")]
    files = total = 0
    for folder, count, size, suffix in layout:
        directory = root / folder
        directory.mkdir(parents=True)
        for index in range(count):
            (directory / f"file-{index:05d}{suffix}").write_bytes(os.urandom(size))
            files, total = files + 1, total + size
    return files, total


def plain_upload(client: object, root: Path, prefix: str) -> None:
    """Every file by boto3's ``upload_file`` (its own multipart and threads for large files)."""
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        client.upload_file(str(path), BUCKET, f"{prefix}{path.relative_to(root)}")  # type: ignore[attr-defined]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3, help="alternations of the two uploads (median compared)")
    parser.add_argument("--large", type=int, default=4, help="large files (videos)")
    parser.add_argument("--large-mb", type=int, default=8, help="size of each large file, MiB")
    parser.add_argument("--medium", type=int, default=64, help="256 KiB files (parquet)")
    parser.add_argument("--small", type=int, default=400, help="4 KiB files (metadata, images)")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="armnet-bench-upload-") as tmp, SeaweedS3(Path(tmp) / "s3") as server:
        root = Path(tmp) / "output"
        files, total = make_output(root, args.large, args.large_mb, args.medium, args.small)
        store = ObjectStore(StoreConfig(bucket=BUCKET, access_key_id=server.access_key,
                                        secret_access_key=server.secret_key, endpoint_url=server.endpoint,
                                        region=server.region))
        store.ensure_bucket()
        plain = server.client()
        upload_output(root, store, "warm", uuid.uuid4().hex)  # first writes grow the bucket's volume: not timed
        seconds: dict[str, list[float]] = {"agent": [], "plain": []}
        for _ in range(args.rounds):
            started = time.perf_counter()
            report = upload_output(root, store, "bench", uuid.uuid4().hex)
            seconds["agent"].append(time.perf_counter() - started)
            if len(report.artifacts) != files or report.uploaded_bytes != total:
                raise SystemExit(f"the agent stored {len(report.artifacts)} of {files} files: {report.refused}")
            started = time.perf_counter()
            plain_upload(plain, root, f"plain/{uuid.uuid4().hex}/")
            seconds["plain"].append(time.perf_counter() - started)

    mib = total / (1 << 20)
    print(f"{files} files, {mib:.1f} MiB ({args.large} x {args.large_mb} MiB, {args.medium} x 256 KiB, "
          f"{args.small} x 4 KiB), {args.rounds} rounds")
    print(f"{'upload':<8} {'median s':>9} {'MiB/s':>8} {'files/s':>8}")
    median = {mode: statistics.median(values) for mode, values in seconds.items()}
    for mode, value in median.items():
        print(f"{mode:<8} {value:>9.2f} {mib / value:>8.1f} {files / value:>8.0f}")
    ratio = median["plain"] / median["agent"]
    print(f"agent / plain throughput: {ratio:.2f}x (target >= {TARGET}x) {'ok' if ratio >= TARGET else 'MISSED'}")
    return 0 if ratio >= TARGET else 1


if __name__ == "__main__":
    raise SystemExit(main())
