"""Options every client command shares (kubectl's), and turning client errors into one line + exit code."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..errors import ClientError

if TYPE_CHECKING:
    from ..client import Client

EXIT_ERROR = 1


def add_cluster_options(parser: argparse.ArgumentParser, examples: str) -> None:
    """``-n/--namespace``, ``--context``, ``--kubeconfig``, ``--nats-url`` and the examples epilog."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = "examples:\n" + examples.strip("\n")
    group = parser.add_argument_group("cluster (resolved like kubectl)")
    group.add_argument("-n", "--namespace", help="namespace (default: the context's, else default)")
    group.add_argument("--context", help="kubeconfig context (default: current-context)")
    group.add_argument("--kubeconfig", help="kubeconfig file (default: $KUBECONFIG, ~/.kube/config)")
    group.add_argument("--nats-url", help="NATS server with the job logs (default: $ARMNET_NATS_URL, $NATS_URL)")


def client_from(args: argparse.Namespace) -> Client:
    from ..client import Client

    return Client(namespace=args.namespace, context=args.context, kubeconfig=args.kubeconfig,
                  nats_url=args.nats_url)


def guarded(body: Callable[[], int], *, error_code: int = EXIT_ERROR) -> int:
    """Run ``body``; a :class:`ClientError` becomes ``error: <message>`` on stderr and ``error_code``."""
    try:
        return body()
    except ClientError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return error_code
    except KeyboardInterrupt:
        return 130
