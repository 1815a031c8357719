"""``armnet submit``: create a RobotJob from a file or flags; follow it unless ``--detach``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from armnet_core.models import JobSpec
from pydantic import ValidationError

from ..errors import InvalidJob
from ..mapping import robotjob_body
from ..render import result_exit_code
from .common import add_cluster_options, client_from, guarded
from .printer import LogPrinter

#: ``spec.preflight.seconds``'s bounds (the CRD's).
MAX_PREFLIGHT_SECONDS = 3600

EXAMPLES = """
  armnet submit -f job.yaml                         # a RobotJob manifest, as for kubectl apply
  armnet submit --image ghcr.io/acme/pick:1.2 --embodiment lerobot/so-101 \\
      --task pick-cube --args '{"episodes": 10}' --timeout 600 --secret HF_TOKEN=hf-token
  armnet submit --detach --image localhost/pick:dev --embodiment lerobot/so-101
  armnet submit --image localhost/pick:dev --embodiment lerobot/so-101 --preflight 60 --priority 5
prints the job's name; without --detach it then follows the output like
`armnet logs -f` and exits like `armnet result`: 0 succeeded, 1 failed/timeout/cancelled.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-f", "--filename", help="a RobotJob manifest (YAML or JSON); - for stdin")
    parser.add_argument("--image", help="the job's image, built on the armnet runtime base image")
    parser.add_argument("--embodiment", help="robot embodiment, e.g. lerobot/so-101")
    parser.add_argument("--task", help="only cells set up for this task run it")
    parser.add_argument("--args", default="{}", help="JSON object passed to @main as ctx.args")
    parser.add_argument("--timeout", type=int, default=120, help="wall-clock cap in seconds (120)")
    parser.add_argument("--secret", action="append", default=[], metavar="ENV=NAME",
                        help="inject Secret NAME of the namespace as env var ENV (repeatable)")
    parser.add_argument("--name", help="the RobotJob's name (default: generated from the image)")
    parser.add_argument("--detach", action="store_true", help="print the name and return; the job "
                        "keeps running when this client goes away")
    parser.add_argument("--priority", type=int, help="the job's priority within its tenant (higher runs "
                        "first; with the tenant's CellQuota allowing it, it may preempt its own lower ones)")
    parser.add_argument("--preflight", type=int, metavar="S", help="first run the job for at most S seconds "
                        "on a simulated twin of its embodiment: it waits for a real cell only if that passes")
    parser.add_argument("--follower-timeout", type=float, default=30.0, metavar="S",
                        help="without --detach: the node agent cancels the job when this client's "
                        "heartbeats stop for S seconds (a crash, a closed laptop); default 30")
    add_cluster_options(parser, EXAMPLES)


def spec_from_flags(args: argparse.Namespace) -> JobSpec:
    """The ``JobSpec`` of the flags; :class:`InvalidJob` names the flag that is wrong."""
    if not args.image or not args.embodiment:
        raise InvalidJob("give -f job.yaml, or both --image and --embodiment")
    try:
        job_args = json.loads(args.args)
    except ValueError as exc:
        raise InvalidJob(f"--args must be a JSON object: {exc}") from exc
    if not isinstance(job_args, dict):
        raise InvalidJob("--args must be a JSON object, e.g. '{\"episodes\": 10}'")
    secrets: dict[str, str] = {}
    for item in args.secret:
        env, sep, name = item.partition("=")
        if not sep or not env or not name:
            raise InvalidJob(f"--secret {item!r}: use ENV=secret-name, e.g. HF_TOKEN=hf-token")
        secrets[env] = name
    try:
        return JobSpec(image=args.image, embodiment=args.embodiment, task=args.task, args=job_args,
                       timeout_seconds=args.timeout, secrets=secrets, detach=args.detach)
    except ValidationError as exc:
        raise InvalidJob(f"invalid job: {exc}") from exc


def spec_extras(args: argparse.Namespace) -> dict[str, Any]:
    """The ``RobotJob.spec`` fields the flags set that ``JobSpec`` (the SDK's model) has no field for.

    They go into the manifest as written, over a ``-f`` manifest's own, like ``--detach``.
    """
    extras: dict[str, Any] = {}
    if args.priority is not None:
        extras["priority"] = args.priority
    if args.preflight is not None:
        if not 1 <= args.preflight <= MAX_PREFLIGHT_SECONDS:
            raise InvalidJob(f"--preflight takes 1 to {MAX_PREFLIGHT_SECONDS} seconds, not {args.preflight}")
        extras["preflight"] = {"seconds": args.preflight}
    return extras


def read_manifest(path: str) -> dict[str, Any]:
    import yaml

    text = sys.stdin.read() if path == "-" else Path(path).read_text()
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InvalidJob(f"{path} is not YAML or JSON: {exc}") from exc
    if not isinstance(document, dict):
        raise InvalidJob(f"{path} must hold one RobotJob manifest")
    return document


def run(args: argparse.Namespace) -> int:
    def body() -> int:
        client = client_from(args)
        client.follower_timeout_s = args.follower_timeout
        # Heartbeats need NATS: without a URL the follow polls the status and declares no follower.
        follow = not args.detach and client.nats_url is not None
        extras = spec_extras(args)
        if args.filename:
            manifest = read_manifest(args.filename)
            if args.detach:
                manifest.setdefault("spec", {})["detach"] = True
            manifest.setdefault("spec", {}).update(extras)
            job = client.submit_manifest(manifest, namespace=args.namespace, follow=follow)
        elif extras:
            manifest = robotjob_body(spec_from_flags(args), namespace=client.namespace, name=args.name)
            manifest["spec"].update(extras)
            job = client.submit_manifest(manifest, namespace=args.namespace, follow=follow)
        else:
            job = client.submit(spec_from_flags(args), name=args.name, follow=follow)
        print(job.id, flush=True)
        if args.detach:
            return 0
        printer = LogPrinter(sys.stderr, live=sys.stderr.isatty())
        try:
            for line in client.logs(job.id, follow=True):
                printer.show(line)
        finally:
            printer.close()
        # The stream's last line can precede the agent's status write: wait for the status (not for
        # the output's upload: `armnet artifacts` says where it went).
        return result_exit_code(client.wait_terminal(job.id, None, stored_output=False)[1].status)

    return guarded(body)
