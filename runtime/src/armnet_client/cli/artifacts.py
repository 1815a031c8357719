"""``armnet artifacts JOB``: where a job's output went; ``--files`` lists it, ``--download DIR`` fetches it."""

from __future__ import annotations

import argparse
from pathlib import Path

from armnet_core.api import ArtifactsPhase, JobPhase

from ..artifacts import download, open_manifest
from .common import add_cluster_options, client_from, guarded

#: Exit codes: 0 read (or fetched), 1 an error, 2 nothing stored (yet).
EXIT_NOT_STORED = 2

EXAMPLES = """
  armnet artifacts pick-7x2k                      # Uploaded: 12 files, 3.4 MB at s3://outputs/team-a/<uid>/
  armnet artifacts pick-7x2k --files              # every file with its size and SHA-256
  armnet artifacts pick-7x2k --download ./pick    # fetch them, each checked against its SHA-256
  # the store's URL and your read credentials:
  ARMNET_ARTIFACTS_ENDPOINT=http://s3.lab:8333 AWS_ACCESS_KEY_ID=... AWS_SECRET_ACCESS_KEY=... \\
    armnet artifacts pick-7x2k --download ./pick
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("job", help="the RobotJob name")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--files", action="store_true", help="list every stored file (reads the manifest)")
    what.add_argument("--download", metavar="DIR", type=Path,
                      help="fetch every stored file below DIR (files already there unchanged are kept)")
    parser.add_argument("--endpoint", help="the object store's URL (default: $ARMNET_ARTIFACTS_ENDPOINT, else AWS S3)")
    add_cluster_options(parser, EXAMPLES)


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        job = client_from(args).read(args.job)
        stored = job.status.artifacts
        if stored is None or stored.phase is None:
            print(f"robotjob {args.job} has no stored output yet (phase {job.status.phase or JobPhase.SUBMITTED}): "
                  "the node agent stores it after the job ends")
            return EXIT_NOT_STORED
        if stored.phase != ArtifactsPhase.UPLOADED or not stored.location or not stored.manifest:
            waiting = "the job ended; its output waits in the node agent's upload queue"
            print(f"{stored.phase}: {stored.message or (waiting if stored.phase == ArtifactsPhase.PENDING else 'nothing stored')}")
            return EXIT_NOT_STORED
        whole = "" if stored.complete is not False else " (incomplete: a file changed while it was stored)"
        print(f"Uploaded: {stored.files} files, {stored.bytes} bytes at {stored.location}{whole}")
        if stored.message:
            print(stored.message)
        if not (args.files or args.download):
            return 0
        store, manifest = open_manifest(stored.location, stored.manifest, endpoint_url=args.endpoint)
        if args.files:
            for item in manifest.files:
                print(f"{item.bytes:>12}  {item.sha256}  {item.path}")
            return 0
        done = download(store, manifest, args.download)
        print(f"downloaded {len(done.written)} files to {args.download}"
              + (f" ({len(done.unchanged)} already there)" if done.unchanged else ""))
        return 0

    return guarded(body)
