"""An in-memory stand-in for the API server's optimistic concurrency, for property tests.

It is not a Kubernetes mock for integration: it models exactly the rules
the binder's safety rests on (JSON merge patch, resourceVersion preconditions
that fail with Conflict, and the JSON Patch ops the finalizer uses) so hypothesis can explore thousands of interleavings
in seconds. The integration tests check the same code against the real server.
"""

from __future__ import annotations

import copy
from datetime import UTC, datetime, timedelta
from typing import Any

from armnet_core.api import TERMINAL_PHASES
from armnet_core.times import kube_time
from armnet_operator.errors import AlreadyExists, Conflict, NotFound, StoreError
from armnet_operator.model import Cell, Job
from armnet_operator.parsing import parse_cell, parse_job
from armnet_operator.patches import Patch, Target
from armnet_operator.quota import QuotaObject


class Crash(BaseException):
    """The operator process dies mid-pass (a BaseException: no per-object guard may swallow it)."""


def merge(target: dict[str, Any], patch: dict[str, Any]) -> dict[str, Any]:
    for key, value in patch.items():
        if value is None:
            target.pop(key, None)
        elif isinstance(value, dict):
            # RFC 7386: an object patched onto a missing or non-object value patches an empty object
            # (its nulls remove nothing and are not stored).
            target[key] = merge(target[key] if isinstance(target.get(key), dict) else {}, value)
        else:
            target[key] = copy.deepcopy(value)
    return target


def apply_json_patch(obj: dict[str, Any], operations: tuple[dict[str, Any], ...], key: str) -> None:
    """The RFC 6902 ops the operator sends (``test``, ``add``), all or nothing, as the server does.

    A failing op raises Conflict, which is what ``kube`` makes of the server's 422.
    """
    result = copy.deepcopy(obj)
    for op in operations:
        *parents, last = op["path"].strip("/").split("/")
        node: Any = result
        for part in parents:
            if not isinstance(node, dict) or part not in node:
                raise Conflict(f"{key}: no {op['path']}")
            node = node[part]
        if op["op"] == "test":
            if (node.get(last) if isinstance(node, dict) else None) != op["value"]:
                raise Conflict(f"{key}: test of {op['path']} failed")
        elif op["op"] == "add" and isinstance(node, list) and last == "-":
            node.append(copy.deepcopy(op["value"]))
        elif op["op"] == "add" and isinstance(node, dict):
            node[last] = copy.deepcopy(op["value"])
        else:
            raise Conflict(f"{key}: cannot {op['op']} {op['path']}")
    obj.clear()
    obj.update(result)


class World:
    def __init__(self) -> None:
        self.now = datetime(2026, 1, 1, tzinfo=UTC)
        self.rv = 0
        self.jobs: dict[str, dict[str, Any]] = {}
        self.cells: dict[str, dict[str, Any]] = {}
        self.quotas: dict[str, dict[str, Any]] = {}
        self.crash_after: int | None = None
        self.events: list[tuple[str, str]] = []
        self.outputs_bucket: str | None = None
        """The object store of job outputs (``Api.outputs_bucket``); None: the operator has none."""
        self.stored: dict[str, bytes] = {}
        """Its objects by key, as the node agent stored them."""
        self.store_down = False

    def _next_rv(self) -> str:
        self.rv += 1
        return str(self.rv)

    def tick(self, seconds: float) -> None:
        self.now += timedelta(seconds=seconds)

    # ---- what users and agents do
    def submit(self, name: str, embodiment: str, task: str | None, priority: int, **extra: Any) -> None:
        spec: dict[str, Any] = {"image": "localhost/job:dev", "embodiment": embodiment, "priority": priority, **extra}
        if task:
            spec["task"] = task
        meta = {"name": name, "namespace": "t", "uid": f"uid-{name}", "resourceVersion": self._next_rv(),
                "creationTimestamp": kube_time(self.now)}
        self.jobs[f"t/{name}"] = {"metadata": meta, "spec": spec, "status": {}}

    def add_cell(self, name: str, embodiment: str, task: str | None, **extra: Any) -> None:
        spec: dict[str, Any] = {"embodiment": embodiment, "nodeName": f"host-{name}", **extra}
        if task:
            spec["task"] = task
        meta = {"name": name, "resourceVersion": self._next_rv()}
        self.cells[name] = {"metadata": meta, "spec": spec, "status": {}}

    def heartbeat(self, name: str) -> None:
        cell = self.cells[name]
        cell["status"]["lastHeartbeatTime"] = kube_time(self.now)
        cell["metadata"]["resourceVersion"] = self._next_rv()

    def user_patch_job(self, key: str, spec: dict[str, Any]) -> None:
        if key in self.jobs:
            merge(self.jobs[key]["spec"], spec)
            self.jobs[key]["metadata"]["resourceVersion"] = self._next_rv()

    def agent_set_phase(self, key: str, phase: str) -> None:
        body = self.jobs[key]
        body["status"]["phase"] = phase
        if phase in TERMINAL_PHASES:
            body["status"]["finishedAt"] = kube_time(self.now)
        body["metadata"]["resourceVersion"] = self._next_rv()

    # ---- the operator's Api
    def patch(self, patch: Patch) -> dict[str, Any]:
        if self.crash_after is not None:
            if self.crash_after == 0:
                raise Crash()
            self.crash_after -= 1
        cluster = {Target.CELL_STATUS: self.cells, Target.QUOTA_STATUS: self.quotas}
        store = cluster.get(patch.target, self.jobs)
        key = patch.name if patch.target in cluster else f"{patch.namespace}/{patch.name}"
        if key not in store:
            raise NotFound(key)
        obj = store[key]
        if patch.operations:
            apply_json_patch(obj, patch.operations, key)
            obj["metadata"]["resourceVersion"] = self._next_rv()
            return copy.deepcopy(obj)
        body = copy.deepcopy(patch.body)
        wanted = body.get("metadata", {}).pop("resourceVersion", None)
        if wanted is not None and wanted != obj["metadata"]["resourceVersion"]:
            raise Conflict(key)
        if patch.target is Target.JOB:
            merge(obj["metadata"], body.get("metadata", {}))
            merge(obj.setdefault("spec", {}), body.get("spec", {}))
        else:
            merge(obj.setdefault("status", {}), body.get("status", {}))
        obj["metadata"]["resourceVersion"] = self._next_rv()
        if obj["metadata"].get("deletionTimestamp") and not obj["metadata"].get("finalizers"):
            del store[key]
        return copy.deepcopy(obj)

    def read_job(self, namespace: str, name: str) -> dict[str, Any]:
        key = f"{namespace}/{name}"
        if key not in self.jobs:
            raise NotFound(key)
        return copy.deepcopy(self.jobs[key])

    def create_job(self, body: dict[str, Any]) -> dict[str, Any]:
        meta = body["metadata"]
        key = f"{meta['namespace']}/{meta['name']}"
        if key in self.jobs:
            raise AlreadyExists(key)
        created = copy.deepcopy(body)
        created["metadata"].update(uid=f"uid-{meta['name']}", resourceVersion=self._next_rv(),
                                   creationTimestamp=kube_time(self.now))
        created.setdefault("status", {})
        self.jobs[key] = created
        return copy.deepcopy(created)

    def read_cell(self, name: str) -> dict[str, Any]:
        if name not in self.cells:
            raise NotFound(name)
        return copy.deepcopy(self.cells[name])

    def delete_job(self, namespace: str, name: str, uid: str) -> None:
        key = f"{namespace}/{name}"
        if key not in self.jobs:
            raise NotFound(key)
        if self.jobs[key]["metadata"].get("finalizers"):
            self.jobs[key]["metadata"]["deletionTimestamp"] = kube_time(self.now)
            self.jobs[key]["metadata"]["resourceVersion"] = self._next_rv()
        else:
            del self.jobs[key]

    def remove_outputs(self, prefix: str) -> int:
        if self.store_down:
            raise StoreError(f"the store did not answer removing {prefix}")
        gone = [key for key in self.stored if key.startswith(prefix)]
        for key in gone:
            del self.stored[key]
        return len(gone)

    def post_event(self, subject: Job | Cell | QuotaObject, type_: str, reason: str, message: str) -> None:
        self.events.append((subject.key if isinstance(subject, Job) else subject.name, reason))

    # ---- snapshots
    def snapshot(self) -> tuple[list[Job], list[Any]]:
        jobs = [parse_job(copy.deepcopy(b)) for b in self.jobs.values()]
        cells = [parse_cell(copy.deepcopy(b)) for b in self.cells.values()]
        return jobs, cells
