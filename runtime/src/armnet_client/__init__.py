"""armnet's customer client: submit RobotJobs, follow their logs, get their typed results.

Installed with ``pip install 'armnet-runtime[client]'`` (kubernetes, nats-py,
pyyaml). It lives beside ``armnet_runtime`` but is a separate import package so
the SDK inside a job's container still loads only pydantic and the standard
library. Importing this package is cheap: the Kubernetes and NATS libraries are
loaded when a :class:`Client` first talks to a server.

    from armnet_client import execute
    from armnet_runtime import JobSpec

    result = execute(JobSpec(image="ghcr.io/acme/pick:1.2", embodiment="lerobot/so-101"))
    result.raise_for_status()
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .errors import (
    ClientError,
    ClusterUnreachable,
    Conflict,
    CrdsMissing,
    Forbidden,
    InvalidJob,
    JobNotFound,
    NamespaceNotFound,
    NatsForbidden,
    NatsUnreachable,
    NoClusterConfigured,
    WaitTimeout,
)

if TYPE_CHECKING:
    from .client import Client, cancel, execute, get, logs, submit, wait
    from .logwire import LogLine

__all__ = [
    "Client",
    "ClientError",
    "ClusterUnreachable",
    "Conflict",
    "CrdsMissing",
    "Forbidden",
    "InvalidJob",
    "JobNotFound",
    "LogLine",
    "NamespaceNotFound",
    "NatsForbidden",
    "NatsUnreachable",
    "NoClusterConfigured",
    "WaitTimeout",
    "cancel",
    "execute",
    "get",
    "logs",
    "submit",
    "wait",
]

_LAZY = {"Client": "client", "cancel": "client", "execute": "client", "get": "client",
         "logs": "client", "submit": "client", "wait": "client", "LogLine": "logwire"}


def __getattr__(name: str) -> Any:
    """Load the client module on first use, so ``armnet --help`` never imports it."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'armnet_client' has no attribute {name!r}")
    from importlib import import_module

    return getattr(import_module(f"{__name__}.{module}"), name)
