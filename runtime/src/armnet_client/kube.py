"""Finding the cluster like kubectl does, and turning the apiserver's refusals into typed errors.

Resolution order (kubectl's): ``--kubeconfig``, then ``$KUBECONFIG`` (a
``:``-separated list, merged), then ``~/.kube/config``, then the in-cluster
service account. The namespace: ``--namespace``, then the context's namespace,
then the service account's namespace in a pod, then ``default``. The choices
are pure functions; only :func:`connect` reads files and builds an ``ApiClient``
(never the ``kubernetes`` package's global configuration: two clients in one
process may point at two clusters).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from .errors import (
    ClientError,
    ClusterUnreachable,
    Conflict,
    CrdsMissing,
    Forbidden,
    InvalidJob,
    JobNotFound,
    NamespaceNotFound,
    NoClusterConfigured,
)

SERVICE_ACCOUNT_DIR = Path("/var/run/secrets/kubernetes.io/serviceaccount")
DEFAULT_KUBECONFIG = Path("~/.kube/config")


@dataclass(frozen=True)
class ClusterTarget:
    """What the user asked for (flags); ``None`` means "as kubectl would decide"."""

    kubeconfig: Optional[str] = None
    context: Optional[str] = None
    namespace: Optional[str] = None


@dataclass(frozen=True)
class Connection:
    api_client: Any
    namespace: str
    context: Optional[str]


def choose_kubeconfig(flag: Optional[str], env: Mapping[str, str], home_config: Path) -> Optional[str]:
    """The kubeconfig path(s) to load, or ``None`` when there is none (try in-cluster).

    Raises :class:`NoClusterConfigured` for an explicit ``--kubeconfig`` that does
    not exist: silently falling back would talk to another cluster.
    """
    if flag:
        if not Path(flag).expanduser().is_file():
            raise NoClusterConfigured(f"kubeconfig {flag} does not exist (from --kubeconfig)")
        return str(Path(flag).expanduser())
    listed = [p for p in env.get("KUBECONFIG", "").split(os.pathsep) if p]
    existing = [p for p in listed if Path(p).expanduser().is_file()]
    if existing:
        return os.pathsep.join(existing)
    home = home_config.expanduser()
    return str(home) if home.is_file() else None


def choose_namespace(
    flag: Optional[str], context_namespace: Optional[str], pod_namespace: Optional[str]
) -> str:
    return flag or context_namespace or pod_namespace or "default"


def connect(target: ClusterTarget, env: Optional[Mapping[str, str]] = None) -> Connection:
    """An ``ApiClient`` and the namespace for ``target``; :class:`NoClusterConfigured` if none."""
    from kubernetes import client as kclient
    from kubernetes import config as kconfig
    from kubernetes.config.config_exception import ConfigException

    environ = os.environ if env is None else env
    path = choose_kubeconfig(target.kubeconfig, environ, DEFAULT_KUBECONFIG)
    if path is None:
        if not environ.get("KUBERNETES_SERVICE_HOST"):
            raise NoClusterConfigured(
                "no cluster configured: no kubeconfig found (looked at --kubeconfig, $KUBECONFIG, "
                "~/.kube/config) and not running in a pod; pass --kubeconfig or set KUBECONFIG"
            )
        configuration = kclient.Configuration()
        try:
            kconfig.load_incluster_config(client_configuration=configuration)  # type: ignore[no-untyped-call]
        except ConfigException as exc:
            raise NoClusterConfigured(f"in-cluster configuration failed: {exc}") from exc
        namespace_file = SERVICE_ACCOUNT_DIR / "namespace"
        pod_ns = namespace_file.read_text().strip() if namespace_file.is_file() else None
        return Connection(
            kclient.ApiClient(configuration), choose_namespace(target.namespace, None, pod_ns), None
        )
    try:
        contexts, active = kconfig.list_kube_config_contexts(config_file=path)  # type: ignore[no-untyped-call]
        chosen = active
        if target.context:
            chosen = next((c for c in contexts if c["name"] == target.context), None)
            if chosen is None:
                names = ", ".join(sorted(c["name"] for c in contexts)) or "none"
                raise NoClusterConfigured(
                    f"context {target.context!r} not found in {path} (contexts: {names})"
                )
        api_client = kconfig.new_client_from_config(  # type: ignore[no-untyped-call]
            config_file=path, context=chosen["name"] if chosen else None, persist_config=False
        )
    except ConfigException as exc:
        raise NoClusterConfigured(f"kubeconfig {path} is not usable: {exc}") from exc
    context_ns = (chosen or {}).get("context", {}).get("namespace")
    return Connection(
        api_client, choose_namespace(target.namespace, context_ns, None), (chosen or {}).get("name")
    )


def _status_body(body: Any) -> Any:
    if isinstance(body, bytes):
        body = body.decode("utf-8", errors="replace")
    try:
        return json.loads(body) if isinstance(body, str) else body
    except ValueError:
        return None


def api_message(body: Any) -> str:
    """The ``message`` of a Kubernetes ``Status`` body, or the raw body when it is not one."""
    parsed = _status_body(body)
    if isinstance(parsed, dict) and isinstance(parsed.get("message"), str):
        return str(parsed["message"])
    if isinstance(body, bytes):
        body = body.decode("utf-8", errors="replace")
    return str(body)[:500]


def missing_object(body: Any) -> Optional[tuple[str, str]]:
    """(kind, name) of what a 404 ``Status`` says is missing; None when it names nothing.

    The apiserver names the object it did not find (``details``: a robotjob, or the
    namespace a create went to) and names nothing when it does not serve the
    resource at all (its CRD is not installed).
    """
    parsed = _status_body(body)
    details = parsed.get("details") if isinstance(parsed, dict) else None
    if not isinstance(details, dict) or not details.get("name"):
        return None
    return str(details.get("kind") or ""), str(details["name"])


def translate(
    status: int, body: Any, *, verb: str, resource: str, namespace: Optional[str],
    name: Optional[str] = None,
) -> ClientError:
    """The typed error for an apiserver answer ``status`` to ``verb resource [name]``."""
    message = api_message(body)
    if status == 404:
        missing = missing_object(body)
        if missing is None:
            return CrdsMissing(resource, message)
        if missing[0] == "namespaces":
            return NamespaceNotFound(missing[1])
        if name is not None and namespace is not None:
            return JobNotFound(name, namespace)
    if status == 403:
        return Forbidden(verb, resource, namespace, message)
    if status == 401:
        return ClientError(
            f"unauthorized: the cluster rejected your credentials ({message}); refresh your "
            "kubeconfig's token or certificate"
        )
    if status in (400, 422):
        return InvalidJob(f"the cluster refused the {resource}: {message}")
    if status == 409:
        return Conflict(f"conflict on {resource} {name or ''}: {message}".replace("  ", " "))
    if status == 404:
        return ClientError(f"{resource} not found: {message}")
    return ClientError(f"the cluster answered {status} to {verb} {resource}: {message}")


def unreachable(exc: BaseException, server: str) -> ClusterUnreachable:
    return ClusterUnreachable(
        f"cannot reach the cluster at {server}: {exc}; check the kubeconfig's server and your network"
    )
