"""The operator's only door to the Kubernetes API (besides kopf's watches).

Implements ``reconcile.Api`` with the official client: JSON merge patches with
resourceVersion preconditions (JSON Patches for adding the finalizer), deletes with a UID precondition, Events, and the
leader Lease. Maps HTTP errors onto the operator's error tree.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any, cast

from armnet_core.api import API_VERSION, CELLQUOTAS, CELLS, GROUP, ROBOTJOBS, VERSION
from armnet_core.times import kube_time, micro_time
from kubernetes import client, config
from kubernetes.client import rest
from kubernetes.client.exceptions import ApiException

from .errors import (
    AlreadyExists,
    Conflict,
    NotFound,
    PermanentError,
    ResourceMissing,
    StoreError,
    TransientError,
)
from .leader import LeaseMove, LeaseSeen, LeaseView, decide_lease, observe
from .model import Cell, Job
from .outputs_store import OutputsStore
from .patches import Patch, Target
from .quota import QuotaObject

log = logging.getLogger(__name__)
EVENT_MAX_DELAY = 5.0
EVENT_FLUSH_SECONDS = 3.0
"""At shutdown, the Events still queued are posted for at most this long; the rest are dropped (and counted)."""
EVENT_REQUEST_TIMEOUT = (2.0, 3.0)
"""Connect and read timeout of one Event post: a best-effort write, and what bounds the poster's join."""
REQUEST_TIMEOUT = (5.0, 30.0)
"""Connect and read timeout of every other request: a pass stuck on a dead connection cannot hold a stop forever."""
CONNECT_RETRIES = 3
"""urllib3's default: a request whose connection fails is tried this many times more."""
WRITERS = 16  # concurrent writes within a pass (objects are disjoint; preconditions keep them safe)
CONNECTIONS = WRITERS + 4  # + the Event poster, the Lease, headroom


def make_client(kubeconfig: str | None) -> client.ApiClient:
    """In-cluster config when running in a pod, else the kubeconfig (``KUBECONFIG``)."""
    if kubeconfig:
        return _pooled(cast(client.ApiClient, config.new_client_from_config(config_file=kubeconfig)))  # type: ignore[no-untyped-call]
    try:
        config.load_incluster_config()  # type: ignore[no-untyped-call]
    except config.ConfigException:
        return _pooled(cast(client.ApiClient, config.new_client_from_config()))  # type: ignore[no-untyped-call]
    return _pooled(client.ApiClient())


def _pooled(api_client: client.ApiClient) -> client.ApiClient:
    """One kept-alive connection per concurrent writer (the client's default is 5 per core).

    With fewer, urllib3 drops the surplus connections after each request and the
    next write pays a fresh TLS handshake on both sides.
    """
    api_client.configuration.connection_pool_maxsize = CONNECTIONS
    api_client.rest_client = rest.RESTClientObject(api_client.configuration)
    return api_client


def _translate(error: ApiException, what: str) -> Exception:
    if error.status == 409:
        return Conflict(f"{what}: changed since it was read")
    if error.status == 404:
        if _resource_missing(error):
            return ResourceMissing(
                f"{what}: the API server does not serve this resource: is the CRD (crds/robotjob.yaml, "
                "crds/cell.yaml) installed? The operator waits for it"
            )
        return NotFound(f"{what}: not found")
    if error.status in (401, 403):
        return PermanentError(
            f"{what}: forbidden ({error.reason}); grant the operator's ServiceAccount the RBAC "
            "rules in helm/armnet (robotjobs, robotjobs/status, cells/status, cellquotas, cellquotas/status, "
            "events, leases, "
            "customresourcedefinitions get)"
        )
    if error.status == 422:
        return PermanentError(f"{what}: rejected by the API server: {error.body}")
    return TransientError(f"{what}: HTTP {error.status} {error.reason}")


def _resource_missing(error: ApiException) -> bool:
    """A 404 for the whole resource type (CRD gone), not for one object (whose 404 names it)."""
    try:
        details = (json.loads(error.body or "{}") or {}).get("details") or {}
    except (ValueError, AttributeError):
        return False
    return not details.get("name")


class KubeApi:
    def __init__(
        self, api_client: client.ApiClient, component: str, identity: str,
        monotonic: Callable[[], float] = time.monotonic, outputs: OutputsStore | None = None,
    ) -> None:
        self.outputs = outputs
        """The object store of job outputs, whose prefixes go with their jobs at the TTL; None: none."""
        self.custom = client.CustomObjectsApi(api_client)
        self.core = client.CoreV1Api(api_client)
        self.leases = client.CoordinationV1Api(api_client)
        self.extensions = client.ApiextensionsV1Api(api_client)
        self.component = component
        self.identity = identity
        self.monotonic = monotonic
        """The clock a Lease's expiry is measured on (a test's may be stepped by hand)."""
        self._leases_seen: dict[tuple[str, str], LeaseSeen] = {}
        self._events: queue.SimpleQueue[tuple[Job | Cell | QuotaObject, str, str, str, datetime] | None] = queue.SimpleQueue()
        self._quiet = threading.Event()
        self._quiet.set()
        self._closed = False
        self._flush_until = 0.0
        self._dropped = 0
        # A daemon, so that a KubeApi nobody closes (a test's, a script's) never keeps a process alive; the
        # operator closes its own (``close``) before it exits.
        self._poster = threading.Thread(target=self._post_events, name="armnet-events", daemon=True)
        self._poster.start()

    def close(self, flush_seconds: float = EVENT_FLUSH_SECONDS) -> None:
        """Send no request any more; post the queued Events for at most ``flush_seconds``, drop the rest; join the poster.

        Call it after the last pass. The poster must not be inside a request when the
        interpreter exits: CPython ends a daemon thread that takes the GIL back during
        finalization with ``pthread_exit``, and from inside an HTTPS call (``_ssl``'s
        write) that unwind aborts the process. A pass still running at SIGTERM queued
        its Events after kopf's cleanup, the poster was posting them as ``armnet
        operator`` returned 0, and the process died of SIGABRT (exit -6) instead.

        A pass still running after ``Controller.stop`` gave up on it fails fast from
        here on (``TransientError`` on every request), so it ends once its requests in
        flight do (each bounded by ``REQUEST_TIMEOUT``); what it did not write, the next
        leader's pass does.
        """
        if self._closed:
            return
        self._flush_until = time.monotonic() + flush_seconds
        self._closed = True
        self._quiet.set()  # no pass writes any more: nothing to wait for
        self._events.put(None)  # after every Event queued so far
        self._poster.join(flush_seconds + sum(EVENT_REQUEST_TIMEOUT) * (1 + CONNECT_RETRIES) + 1.0)
        if self._poster.is_alive():
            log.warning("the Event poster is still inside a request; exiting without it")
        if self._dropped:
            log.warning("%d Event(s) not posted: the operator stopped before they went out", self._dropped)

    def _send(self, call: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """Every request but the Events' goes out here: bounded in time, and none after ``close``."""
        if self._closed:
            raise TransientError("the operator is stopping; request not sent")
        return call(*args, _request_timeout=REQUEST_TIMEOUT, **kwargs)

    def writing(self, busy: bool) -> None:
        """While a pass writes, Events wait (until ``EVENT_MAX_DELAY`` after they happened): binds first.

        On a loaded API server every Event is one more write competing with the
        claims and binds of a burst; posting them in the gaps between passes
        keeps submit->bound short and loses nothing.
        """
        if busy and not self._closed:  # once closed the poster flushes: never make it wait
            self._quiet.clear()
        else:
            self._quiet.set()

    # -------------------------------------------------------------- reconcile.Api
    def patch(self, patch: Patch) -> dict[str, Any]:
        what = f"{patch.target} {patch.namespace + '/' if patch.namespace else ''}{patch.name}"
        try:
            if patch.target is Target.CELL_STATUS:
                return cast(dict[str, Any], self._send(self.custom.patch_cluster_custom_object_status,
                    GROUP, VERSION, CELLS, patch.name, patch.body
                ))
            if patch.target is Target.QUOTA_STATUS:
                return cast(dict[str, Any], self._send(self.custom.patch_cluster_custom_object_status,
                    GROUP, VERSION, CELLQUOTAS, patch.name, patch.body
                ))
            if patch.target is Target.JOB_STATUS:
                return cast(dict[str, Any], self._send(self.custom.patch_namespaced_custom_object_status,
                    GROUP, VERSION, patch.namespace, ROBOTJOBS, patch.name, patch.body
                ))
            if patch.operations:
                return cast(dict[str, Any], self._send(self.custom.patch_namespaced_custom_object,
                    GROUP, VERSION, patch.namespace, ROBOTJOBS, patch.name, list(patch.operations),
                    _content_type="application/json-patch+json",
                ))
            return cast(dict[str, Any], self._send(self.custom.patch_namespaced_custom_object,
                GROUP, VERSION, patch.namespace, ROBOTJOBS, patch.name, patch.body
            ))
        except ApiException as error:
            if patch.operations and error.status == 422:
                # A JSON Patch op that cannot apply (a failed ``test``, a missing
                # list): the object changed since we read it, like a 409.
                raise Conflict(f"{what}: changed since it was read ({error.reason})") from error
            raise _translate(error, what) from error

    def read_job(self, namespace: str, name: str) -> dict[str, Any]:
        try:
            return cast(dict[str, Any], self._send(self.custom.get_namespaced_custom_object,
                GROUP, VERSION, namespace, ROBOTJOBS, name
            ))
        except ApiException as error:
            raise _translate(error, f"robotjob {namespace}/{name}") from error

    def create_job(self, body: dict[str, Any]) -> dict[str, Any]:
        """Create a RobotJob (a preempted job's requeue); AlreadyExists when the name is taken."""
        namespace, name = body["metadata"]["namespace"], body["metadata"]["name"]
        try:
            return cast(dict[str, Any], self._send(self.custom.create_namespaced_custom_object,
                GROUP, VERSION, namespace, ROBOTJOBS, body
            ))
        except ApiException as error:
            if error.status == 409:
                raise AlreadyExists(f"robotjob {namespace}/{name}: already exists") from error
            raise _translate(error, f"create robotjob {namespace}/{name}") from error

    def list_quotas(self) -> list[dict[str, Any]]:
        """Every CellQuota (none if the CRD is not installed: nothing is rationed then)."""
        try:
            found = self._send(self.custom.list_cluster_custom_object, GROUP, VERSION, CELLQUOTAS)
        except ApiException as error:
            if error.status == 404:
                return []
            raise _translate(error, "list cellquotas") from error
        return list(cast(dict[str, Any], found).get("items") or [])

    def read_cell(self, name: str) -> dict[str, Any]:
        try:
            return cast(dict[str, Any], self._send(self.custom.get_cluster_custom_object, GROUP, VERSION, CELLS, name))
        except ApiException as error:
            raise _translate(error, f"cell {name}") from error

    @property
    def outputs_bucket(self) -> str | None:
        return self.outputs.bucket if self.outputs is not None else None

    def remove_outputs(self, prefix: str) -> int:
        if self.outputs is None:
            raise StoreError("no object store of job outputs is configured")
        return self.outputs.remove(prefix)

    def delete_job(self, namespace: str, name: str, uid: str) -> None:
        body = client.V1DeleteOptions(preconditions=client.V1Preconditions(uid=uid or None))
        try:
            self._send(self.custom.delete_namespaced_custom_object,
                GROUP, VERSION, namespace, ROBOTJOBS, name, body=body
            )
        except ApiException as error:
            raise _translate(error, f"delete robotjob {namespace}/{name}") from error

    def post_event(self, subject: Job | Cell | QuotaObject, type_: str, reason: str, message: str) -> None:
        """Queue the Event: a slow Events write must never delay a binding."""
        if self._closed:
            self._dropped += 1
            return
        self._events.put((subject, type_, reason, message, datetime.now(UTC)))

    def _post_events(self) -> None:
        while True:
            item = self._events.get()
            if item is None:  # closed, and everything queued before was posted or dropped
                return
            job, type_, reason, message, when = item
            if self._closed and time.monotonic() > self._flush_until:
                self._dropped += 1
                continue
            lag = (datetime.now(UTC) - when).total_seconds()
            self._quiet.wait(max(0.0, EVENT_MAX_DELAY - lag))
            try:
                self._post_event(job, type_, reason, message, when)
            except Exception as error:  # noqa: BLE001 - events are best effort; keep the poster alive
                log.debug("event %s for %s not posted: %s", reason, job, error)

    def _post_event(self, subject: Job | Cell | QuotaObject, type_: str, reason: str, message: str,
                    now: datetime) -> None:
        # Events of a cluster-scoped Cell or CellQuota live in "default", as kubectl describe expects.
        namespace = subject.namespace if isinstance(subject, Job) else "default"
        kind = "RobotJob" if isinstance(subject, Job) else "Cell" if isinstance(subject, Cell) else "CellQuota"
        involved = {"apiVersion": API_VERSION, "kind": kind, "name": subject.name, "uid": subject.uid}
        if isinstance(subject, Job):
            involved["namespace"] = namespace
        body = {
            "metadata": {"generateName": f"{subject.name}.", "namespace": namespace},
            "involvedObject": involved,
            "type": type_, "reason": reason, "message": message[:1024],
            "source": {"component": self.component},
            "reportingComponent": self.component, "reportingInstance": self.identity,
            "firstTimestamp": kube_time(now), "lastTimestamp": kube_time(now), "count": 1,
        }
        try:
            # A plain dict: building the client's model objects costs more CPU than the request.
            self.core.create_namespaced_event(namespace, cast(Any, body), _request_timeout=EVENT_REQUEST_TIMEOUT)
        except ApiException as error:
            raise _translate(error, f"event for {subject.name}") from error

    # -------------------------------------------------------------- the CRDs
    def check_resources(self) -> None:
        """Raise ResourceMissing unless the API server serves both robotjobs and cells.

        One discovery GET. When the RobotJob CRD is deleted, kopf stops its
        watch and the cache empties quietly; this makes the operator say so
        (and hold its writes) until the CRD is back.
        """
        try:
            found = self._send(self.custom.get_api_resources, GROUP, VERSION)
            served = {r.name for r in (found.resources or [])}
        except ApiException as error:
            if error.status != 404:
                raise _translate(error, f"discovery of {GROUP}/{VERSION}") from error
            served = set()  # no CRD of the group is left
        missing = [f"{plural}.{GROUP}" for plural in (ROBOTJOBS, CELLS) if plural not in served]
        if missing:
            raise ResourceMissing(
                f"the CRD(s) {', '.join(missing)} are not served by the API server (deleted or not yet "
                "applied: kubectl apply -f crds/); the operator holds its writes until they are back"
            )

    def crd_uids(self) -> dict[str, str]:
        """The uid of each CRD the operator serves (``robotjobs.armnet.io``: uid); one left out is missing.

        A uid that changed is a CRD deleted and created again, however fast (``kubectl
        replace --force``, a GitOps sync): kopf's watches may have missed it.
        """
        uids: dict[str, str] = {}
        for plural in (ROBOTJOBS, CELLS):
            name = f"{plural}.{GROUP}"
            try:
                crd = self._send(self.extensions.read_custom_resource_definition, name)
            except ApiException as error:
                if error.status != 404:
                    raise _translate(error, f"CRD {name}") from error
                continue
            uids[name] = str(crd.metadata.uid if crd.metadata is not None else "")
        return uids

    # -------------------------------------------------------------- leader Lease
    def hold_lease(self, namespace: str, name: str, duration: timedelta, now: datetime) -> bool:
        """Acquire or renew the Lease; True while this replica leads.

        ``now`` (wall clock) is only written, as renewTime/acquireTime for people reading
        the Lease; whether another holder has expired is measured on ``self.monotonic``.
        """
        try:
            lease = self._send(self.leases.read_namespaced_lease, name, namespace)
        except ApiException as error:
            if error.status != 404:
                raise _translate(error, f"lease {namespace}/{name}") from error
            return self._create_lease(namespace, name, duration, now)
        spec = lease.spec
        view = LeaseView(
            holder=spec.holder_identity if spec else None,
            renewed=spec.renew_time if spec else None,
            duration=timedelta(seconds=(spec.lease_duration_seconds if spec else None) or 15),
            transitions=(spec.lease_transitions if spec else None) or 0,
            acquired=spec.acquire_time if spec else None,
        )
        # Expiry runs on our own clock from when we last saw the record change, never on the
        # holder's renewTime: the two replicas' clocks may disagree by any amount.
        ticks = self.monotonic()
        seen = self._leases_seen[(namespace, name)] = observe(self._leases_seen.get((namespace, name)), view, ticks)
        move = decide_lease(seen, self.identity, ticks)
        if move is LeaseMove.FOLLOW:
            return False
        stamp = micro_time(now)
        patch: dict[str, Any] = {
            "metadata": {"resourceVersion": lease.metadata.resource_version if lease.metadata else None},
            "spec": {"holderIdentity": self.identity, "renewTime": stamp,
                     "leaseDurationSeconds": int(duration.total_seconds())},
        }
        if move is LeaseMove.ACQUIRE:
            patch["spec"].update(acquireTime=stamp, leaseTransitions=view.transitions + 1)
            log.info("acquiring leadership (lease %s/%s) from %s", namespace, name, view.holder)
        try:
            self._send(self.leases.patch_namespaced_lease, name, namespace, patch)
        except ApiException as error:
            if error.status == 409:
                return False
            raise _translate(error, f"lease {namespace}/{name}") from error
        return True

    def _create_lease(self, namespace: str, name: str, duration: timedelta, now: datetime) -> bool:
        stamp = micro_time(now)
        body = {
            "metadata": {"name": name, "namespace": namespace},
            "spec": {"holderIdentity": self.identity, "acquireTime": stamp, "renewTime": stamp,
                     "leaseDurationSeconds": int(duration.total_seconds()), "leaseTransitions": 0},
        }
        try:
            self._send(self.leases.create_namespaced_lease, namespace, cast(client.V1Lease, client.V1Lease.from_dict(body)))
        except ApiException as error:
            if error.status == 409:
                return False
            if error.status == 404:
                raise PermanentError(
                    f"lease namespace {namespace!r} does not exist; create it or set "
                    "ARMNET_OPERATOR_LEASE_NAMESPACE (--lease-namespace)"
                ) from error
            raise _translate(error, f"lease {namespace}/{name}") from error
        log.info("acquired leadership (new lease %s/%s)", namespace, name)
        return True
