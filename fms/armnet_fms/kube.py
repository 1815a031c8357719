"""The FMS's Kubernetes reads and writes: Cells, the jobs they run, cordon, cancel, audit Events.

Synchronous (the ``kubernetes`` client); the web layer calls it from a worker
thread. It writes only what a cell operator may change: a Cell's
``spec.unschedulable``, a running RobotJob's ``spec.cancel`` (with an
annotation naming who stopped it) and Events. Never a status: the operator and
the agent own those.
"""

from __future__ import annotations

import socket
from datetime import UTC, datetime
from typing import Any, cast

from armnet_core.api import API_VERSION, CELLS, GROUP, ROBOTJOBS, VERSION
from armnet_core.times import kube_time

from .actions import AuditEvent

COMPONENT = "armnet-fms"


class KubeGateway:
    def __init__(self, api_client: Any, *, identity: str = "") -> None:
        from kubernetes import client as kclient

        self.custom = kclient.CustomObjectsApi(api_client)
        self.core = kclient.CoreV1Api(api_client)
        self.identity = identity or socket.gethostname()

    def list_cells(self) -> list[dict[str, Any]]:
        listed = cast(dict[str, Any], self.custom.list_cluster_custom_object(GROUP, VERSION, CELLS))
        return list(listed.get("items", []))

    def list_jobs(self) -> list[dict[str, Any]]:
        """Every RobotJob, in every namespace (the cell page's last-job video asks, on a click)."""
        listed = cast(dict[str, Any], self.custom.list_cluster_custom_object(GROUP, VERSION, ROBOTJOBS))
        return list(listed.get("items", []))

    def get_cell(self, name: str) -> dict[str, Any] | None:
        return self._get(lambda: self.custom.get_cluster_custom_object(GROUP, VERSION, CELLS, name))

    def get_job(self, key: str) -> dict[str, Any] | None:
        namespace, _, name = key.partition("/")
        if not namespace or not name:
            return None
        return self._get(lambda: self.custom.get_namespaced_custom_object(
            GROUP, VERSION, namespace, ROBOTJOBS, name))

    def current_jobs(self, cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """The RobotJobs the cells name in ``status.currentJob`` (one GET each, no cluster-wide job list)."""
        jobs = []
        for cell in cells:
            key = (cell.get("status") or {}).get("currentJob")
            job = self.get_job(key) if isinstance(key, str) else None
            if job is not None:
                jobs.append(job)
        return jobs

    def patch_cell(self, name: str, patch: dict[str, Any]) -> None:
        self.custom.patch_cluster_custom_object(GROUP, VERSION, CELLS, name, patch)

    def patch_job(self, namespace: str, name: str, patch: dict[str, Any]) -> None:
        self.custom.patch_namespaced_custom_object(GROUP, VERSION, namespace, ROBOTJOBS, name, patch)

    def post_event(self, event: AuditEvent) -> None:
        now = kube_time(datetime.now(UTC))
        involved = {"apiVersion": API_VERSION, "kind": event.kind, "name": event.name, "uid": event.uid}
        if event.kind == "RobotJob":
            involved["namespace"] = event.namespace
        body = {
            "metadata": {"generateName": f"{event.name}.", "namespace": event.namespace},
            "involvedObject": involved, "type": event.type, "reason": event.reason,
            "message": event.message[:1024], "source": {"component": COMPONENT},
            "reportingComponent": COMPONENT, "reportingInstance": self.identity[:128],
            "firstTimestamp": now, "lastTimestamp": now, "count": 1,
        }
        self.core.create_namespaced_event(event.namespace, cast(Any, body))

    @staticmethod
    def _get(call: Any) -> dict[str, Any] | None:
        from kubernetes.client.exceptions import ApiException

        try:
            return cast(dict[str, Any], call())
        except ApiException as error:
            if error.status == 404:
                return None
            raise
