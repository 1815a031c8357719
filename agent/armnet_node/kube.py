"""The agent's reads and writes on the API server (the official ``kubernetes`` client).

Reads: Cells (cluster-wide), RobotJobs (all namespaces or the configured
ones), Secrets in a job's own namespace, a ConfigMap key a Cell names (in the
agent's own namespace). Writes: Cell status (heartbeat,
conditions), RobotJob status (run-time fields). Errors become the small set
the agent acts on: :class:`Conflict` (re-read and decide again),
:class:`Gone`, :class:`KubeError`.
"""

from __future__ import annotations

import base64
import logging
from typing import Any, cast

from armnet_core.api import CELLS, GROUP, ROBOTJOBS, VERSION
from kubernetes import client, config
from kubernetes.client.exceptions import ApiException

log = logging.getLogger(__name__)



class KubeError(RuntimeError):
    """A request failed; the message names the object and the HTTP status."""


class Conflict(KubeError):
    """The object changed since it was read (409)."""


class Gone(KubeError):
    """The object does not exist (404)."""


class SecretMissing(KubeError):
    """A Secret or a key of it that a job names is not in the job's namespace."""


class ConfigMapKeyMissing(KubeError):
    """A ConfigMap or a key of it that a Cell names is not in the agent's namespace."""


class ConfigMapForbidden(KubeError):
    """The agent may not read the ConfigMap a Cell names (it is not among the ones its RBAC lists)."""


def make_client(kubeconfig: str | None) -> client.ApiClient:
    """The kubeconfig when given, else in-cluster config, else ``KUBECONFIG``."""
    if kubeconfig:
        return cast(client.ApiClient, config.new_client_from_config(config_file=kubeconfig))  # type: ignore[no-untyped-call]
    try:
        config.load_incluster_config()  # type: ignore[no-untyped-call]
    except config.ConfigException:
        return cast(client.ApiClient, config.new_client_from_config())  # type: ignore[no-untyped-call]
    return client.ApiClient()


def _error(exc: ApiException, what: str) -> KubeError:
    if exc.status == 409:
        return Conflict(f"{what}: changed since it was read")
    if exc.status == 404:
        return Gone(f"{what}: not found")
    if exc.status in (401, 403):
        return KubeError(
            f"{what}: forbidden ({exc.reason}); grant the agent the RBAC rules in docs/agent.md"
        )
    return KubeError(f"{what}: HTTP {exc.status} {exc.reason}: {str(exc.body)[:300]}")


class AgentKube:
    def __init__(self, api_client: client.ApiClient, namespaces: tuple[str, ...] = ()) -> None:
        self.custom = client.CustomObjectsApi(api_client)
        self.core = client.CoreV1Api(api_client)
        self.namespaces = namespaces

    def list_cells(self) -> list[dict[str, Any]]:
        try:
            listed = cast(dict[str, Any], self.custom.list_cluster_custom_object(GROUP, VERSION, CELLS))
        except ApiException as exc:
            raise _error(exc, "list cells") from exc
        return list(listed.get("items", []))

    def list_jobs(self) -> list[dict[str, Any]]:
        try:
            if not self.namespaces:
                listed = cast(dict[str, Any], self.custom.list_cluster_custom_object(GROUP, VERSION, ROBOTJOBS))
                return list(listed.get("items", []))
            items: list[dict[str, Any]] = []
            for namespace in self.namespaces:
                listed = cast(dict[str, Any], self.custom.list_namespaced_custom_object(
                    GROUP, VERSION, namespace, ROBOTJOBS))
                items.extend(listed.get("items", []))
            return items
        except ApiException as exc:
            raise _error(exc, "list robotjobs") from exc

    def read_cell(self, name: str) -> dict[str, Any]:
        try:
            return cast(dict[str, Any], self.custom.get_cluster_custom_object(GROUP, VERSION, CELLS, name))
        except ApiException as exc:
            raise _error(exc, f"cell {name}") from exc

    def read_job(self, namespace: str, name: str) -> dict[str, Any]:
        try:
            return cast(dict[str, Any], self.custom.get_namespaced_custom_object(
                GROUP, VERSION, namespace, ROBOTJOBS, name))
        except ApiException as exc:
            raise _error(exc, f"robotjob {namespace}/{name}") from exc

    def patch_job_status(self, namespace: str, name: str, body: dict[str, Any]) -> dict[str, Any]:
        try:
            return cast(dict[str, Any], self.custom.patch_namespaced_custom_object_status(
                GROUP, VERSION, namespace, ROBOTJOBS, name, body))
        except ApiException as exc:
            raise _error(exc, f"robotjob {namespace}/{name} status") from exc

    def set_job_status_field(self, namespace: str, name: str, uid: str, field: str, value: Any) -> None:
        """``status.<field>`` of the job ``uid`` only; :class:`Gone` when ``name`` is another job now.

        A JSON patch whose first operation tests the uid: a merge patch's ``metadata.uid`` is
        no precondition (measured: the apiserver applied it to a job re-created under the
        name), and a job deleted and re-created meanwhile must not get the old one's field.
        """
        ops = [{"op": "test", "path": "/metadata/uid", "value": uid},
               {"op": "add", "path": f"/status/{field}", "value": value}]
        what = f"robotjob {namespace}/{name} status.{field}"
        try:
            self.custom.patch_namespaced_custom_object_status(GROUP, VERSION, namespace, ROBOTJOBS, name, ops,
                                                              _content_type="application/json-patch+json")
        except ApiException as exc:
            # A failed test is a bare 422 ("rejected ... an error in our request"): the uid tells.
            if exc.status == 422 and (self.read_job(namespace, name).get("metadata") or {}).get("uid") != uid:
                raise Gone(f"{what}: the name is another job's now") from exc
            raise _error(exc, what) from exc

    def patch_cell_status(self, name: str, body: dict[str, Any]) -> dict[str, Any]:
        try:
            return cast(dict[str, Any], self.custom.patch_cluster_custom_object_status(
                GROUP, VERSION, CELLS, name, body))
        except ApiException as exc:
            raise _error(exc, f"cell {name} status") from exc

    def read_config_map_key(self, namespace: str, name: str, key: str) -> bytes:
        """The bytes of ``key`` of ConfigMap ``namespace/name`` (``binaryData``, or ``data`` as UTF-8).

        A missing ConfigMap or key is :class:`ConfigMapKeyMissing`, saying how to make it.
        """
        try:
            found = self.core.read_namespaced_config_map(name, namespace)
        except ApiException as exc:
            if exc.status == 404:
                raise ConfigMapKeyMissing(
                    f"ConfigMap {namespace}/{name} does not exist; create it there: kubectl -n {namespace} "
                    f"create configmap {name} --from-file={key}=<the model file>") from exc
            if exc.status == 403:
                raise ConfigMapForbidden(
                    f"the node agent may not read ConfigMap {namespace}/{name} ({exc.reason}); list it in the Helm "
                    "chart's agent.completionFiles.configMaps (the agent may get exactly those)") from exc
            raise _error(exc, f"configmap {namespace}/{name}") from exc
        binary, text = found.binary_data or {}, found.data or {}
        if key in binary:
            return base64.b64decode(binary[key])
        if key in text:
            return str(text[key]).encode("utf-8")
        raise ConfigMapKeyMissing(
            f"ConfigMap {namespace}/{name} has no key {key!r} (keys: {sorted([*binary, *text])[:20]}); "
            f"add it: kubectl -n {namespace} create configmap {name} --from-file={key}=<the model file> "
            "--dry-run=client -o yaml | kubectl apply -f -")

    def resolve_secrets(self, namespace: str, wanted: dict[str, str]) -> dict[str, str]:
        """Env var -> value from Secrets in ``namespace`` only.

        The value is the Secret's key named like the env var, or its only key.
        A missing Secret or key is :class:`SecretMissing` naming it (never a value).
        """
        values: dict[str, str] = {}
        for env_name, secret_name in sorted(wanted.items()):
            data, key = self._secret_key(namespace, env_name, secret_name)
            values[env_name] = base64.b64decode(data[key]).decode("utf-8", errors="replace")
        return values

    def secret_keys(self, namespace: str, wanted: dict[str, str]) -> list[tuple[str, str, str]]:
        """``(env var, Secret, key)`` per wanted variable, checked like :meth:`resolve_secrets`.

        For the pod launcher: the pod takes the value through a ``secretKeyRef``,
        so the value never passes through the agent into the pod spec.
        """
        return [(env_name, secret_name, self._secret_key(namespace, env_name, secret_name)[1])
                for env_name, secret_name in sorted(wanted.items())]

    def _secret_key(self, namespace: str, env_name: str, secret_name: str) -> tuple[dict[str, Any], str]:
        try:
            secret = self.core.read_namespaced_secret(secret_name, namespace)
        except ApiException as exc:
            if exc.status == 404:
                raise SecretMissing(
                    f"Secret {secret_name!r} (for {env_name}) does not exist in namespace {namespace}; "
                    f"create it there: kubectl -n {namespace} create secret generic {secret_name} "
                    f"--from-literal={env_name}=..."
                ) from exc
            raise _error(exc, f"secret {namespace}/{secret_name}") from exc
        data = secret.data or {}
        key = env_name if env_name in data else (next(iter(data)) if len(data) == 1 else None)
        if key is None:
            raise SecretMissing(
                f"Secret {secret_name!r} in namespace {namespace} has no key {env_name!r} "
                f"(keys: {sorted(data)}); add it or keep one key only"
            )
        return data, key
