"""The client's error tree: every failure a user can act on, with what to do in the message.

The Kubernetes and NATS libraries raise their own exceptions (``ApiException``
with an HTTP status, ``ConfigException``, ``NoServersError``); the client turns
them into these at its edge so callers catch one tree and the CLI prints one
readable line. ``ClientError`` is the base; nothing here imports a library.
"""

from __future__ import annotations


class ClientError(RuntimeError):
    """Base of every error the armnet client raises on purpose."""


class NoClusterConfigured(ClientError):
    """No kubeconfig was found and the process is not inside a cluster."""


class JobNotFound(ClientError, LookupError):
    """The RobotJob does not exist in the namespace asked (or was deleted by its TTL)."""

    def __init__(self, name: str, namespace: str) -> None:
        self.name = name
        self.namespace = namespace
        super().__init__(
            f"robotjob {name!r} not found in namespace {namespace!r}: check the name "
            f"(`armnet get -n {namespace}`) and the namespace (--namespace); finished jobs "
            "are deleted after their ttlSecondsAfterFinished"
        )


class NamespaceNotFound(ClientError, LookupError):
    """The namespace asked for does not exist on the cluster (a typo in --namespace, or the context's)."""

    def __init__(self, namespace: str) -> None:
        self.namespace = namespace
        super().__init__(
            f"namespace {namespace!r} does not exist on this cluster: check --namespace (or the "
            "kubeconfig context's namespace); `kubectl get namespaces` lists them"
        )


class CrdsMissing(ClientError):
    """The cluster does not serve the armnet resources: its CRDs are not installed."""

    def __init__(self, resource: str, detail: str) -> None:
        self.resource = resource
        super().__init__(
            f"this cluster does not serve {resource} ({detail}): the armnet CRDs are not installed; "
            "install the armnet chart (docs/helm.md) or `kubectl apply -f crds/`, or point --context "
            "at the cluster that runs armnet"
        )


class Forbidden(ClientError, PermissionError):
    """The identity in the kubeconfig may not do this in this namespace (RBAC said 403)."""

    def __init__(self, verb: str, resource: str, namespace: str | None, detail: str = "") -> None:
        self.verb = verb
        self.resource = resource
        self.namespace = namespace
        where = f"in namespace {namespace!r}" if namespace else "cluster-wide"
        text = f"forbidden: you may not {verb} {resource} {where}"
        if detail:
            text += f" ({detail})"
        super().__init__(
            text + "; use a namespace you were granted (--namespace) or ask the cluster admin"
        )


class InvalidJob(ClientError, ValueError):
    """The apiserver refused the RobotJob (schema or CEL validation: 422, or a bad request)."""


class Conflict(ClientError):
    """A RobotJob of that name already exists, or a write lost a race (HTTP 409)."""


class ClusterUnreachable(ClientError, ConnectionError):
    """The apiserver did not answer (wrong server address, network, TLS)."""


class NatsUnreachable(ClientError, ConnectionError):
    """The NATS server holding the job logs did not answer; callers fall back to status polling."""


class NatsForbidden(ClientError, PermissionError):
    """The NATS server refused this user the job's log subjects (per-namespace NATS users)."""

    def __init__(self, namespace: str, detail: str) -> None:
        self.namespace = namespace
        super().__init__(
            f"NATS refused reading the logs of namespace {namespace!r} ({detail}): your NATS user "
            "may read only its own namespace's logs; use the credentials of that namespace in "
            "--nats-url (nats://tenant-<namespace>:<password>@host:4222)"
        )


class WaitTimeout(ClientError, TimeoutError):
    """``wait`` gave up before the job reached a terminal phase (the job keeps running)."""


class RerunMissing(ClientError):
    """``armnet view`` into a viewer or ``.rrd`` needs ``rerun-sdk``, which is not installed here."""

    def __init__(self) -> None:
        super().__init__(
            "watching Rerun data needs rerun-sdk: pip install 'armnet-runtime[view]' "
            "(or use --dump for the decoded packets as JSON lines)"
        )
