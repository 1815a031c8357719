"""The armnet client: RobotJobs through the Kubernetes API, their output through JetStream.

Every call maps a library failure to the typed errors of ``errors`` at this
edge. The module-level functions (``submit``, ``get``, ``wait``, ``cancel``,
``execute``, ``logs``) build a :class:`Client` from the environment each time;
there is no hidden process-wide client.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from datetime import datetime
from typing import Any, Optional, TextIO

from armnet_core.api import (
    API_VERSION,
    ARTIFACTS_IN_PROGRESS,
    CELLQUOTAS,
    CELLS,
    GROUP,
    VERSION,
    JobPhase,
)
from armnet_core.api import ROBOTJOBS as JOBS
from armnet_core.models import Job, JobResult, JobSpec
from armnet_core.nats_url import SHARED_ENV as SHARED_NATS_ENV
from armnet_core.nats_url import nats_url_from as resolve_nats_url
from pydantic import ValidationError

from . import kube
from .errors import ClientError, Forbidden, InvalidJob, NatsUnreachable, WaitTimeout
from .heartbeat import DEFAULT_INTERVAL_S, HeartbeatSender
from .logstream import (
    DEFAULT_STREAM,
    CaughtUp,
    Event,
    FollowSettings,
    follow_batches,
    follow_events,
)
from .logwire import LogLine
from .mapping import (
    CellView,
    JobView,
    QuotaView,
    cancel_patch,
    cell_view_of,
    follower_metadata,
    generated_name_prefix,
    job_from_robotjob,
    quota_view_of,
    requeue_of,
    result_from_robotjob,
    robotjob_body,
    view_of,
)
from .resources import Cell, RobotJob, RobotJobSpec
from .results import ClusterJobResult
from .statusfeed import ended, status_events

log = logging.getLogger("armnet_client")

DEFAULT_FOLLOWER_TIMEOUT_S = 30.0
#: How long ``wait``/``execute`` wait past a job's end for its output to be stored (docs/outputs.md).
DEFAULT_ARTIFACTS_WAIT_S = 120.0

NATS_URL_ENV = ("ARMNET_NATS_URL", SHARED_NATS_ENV)


def nats_url_from(flag: Optional[str], env: Mapping[str, str]) -> Optional[str]:
    """``--nats-url``, else ``$ARMNET_NATS_URL``, else ``$NATS_URL`` (what ``armnet dev up`` prints)."""
    return resolve_nats_url(flag, env, NATS_URL_ENV[0])


class Client:
    """One cluster (kubeconfig, context, namespace as kubectl resolves them) and one NATS server."""

    def __init__(
        self, *, namespace: Optional[str] = None, context: Optional[str] = None,
        kubeconfig: Optional[str] = None, nats_url: Optional[str] = None,
        stream: str = DEFAULT_STREAM, poll_interval_s: float = 1.0,
        heartbeat_interval_s: float = DEFAULT_INTERVAL_S, env: Optional[Mapping[str, str]] = None,
        follower_timeout_s: float = DEFAULT_FOLLOWER_TIMEOUT_S,
        artifacts_wait_s: float = DEFAULT_ARTIFACTS_WAIT_S,
    ) -> None:
        environ = os.environ if env is None else env
        self._target = kube.ClusterTarget(kubeconfig, context, namespace)
        self._env = environ
        self._connection: Optional[kube.Connection] = None
        self.nats_url = nats_url_from(nats_url, environ)
        self.stream = stream
        self.poll_interval_s = poll_interval_s
        self.heartbeat_interval_s = heartbeat_interval_s
        #: A job submitted to be followed (``execute``, ``armnet submit``) and not detached is
        #: cancelled by the node agent when this client's heartbeats stop for this long.
        self.follower_timeout_s = follower_timeout_s
        #: ``wait``/``execute`` wait this long past the job's end for the node agent to store its
        #: output (``ClusterJobResult.artifacts``); a longer upload is returned as it stands (``Uploading``).
        self.artifacts_wait_s = artifacts_wait_s

    # ---- cluster access
    @property
    def namespace(self) -> str:
        return self._connect().namespace

    def _connect(self) -> kube.Connection:
        if self._connection is None:
            self._connection = kube.connect(self._target, self._env)
        return self._connection

    def _api(self) -> Any:
        from kubernetes import client as kclient

        return kclient.CustomObjectsApi(self._connect().api_client)

    def _call(
        self, verb: str, resource: str, fn: Callable[[], Any], *, namespace: Optional[str],
        name: Optional[str] = None,
    ) -> Any:
        from kubernetes.client.exceptions import ApiException
        from urllib3.exceptions import HTTPError

        try:
            return fn()
        except ApiException as exc:
            raise kube.translate(exc.status or 0, exc.body, verb=verb, resource=resource,
                                 namespace=namespace, name=name) from exc
        except (HTTPError, OSError) as exc:
            raise kube.unreachable(exc, self._connect().api_client.configuration.host) from exc

    def read(self, name: str) -> RobotJob:
        """The RobotJob as the apiserver has it (validated), for callers that need every field."""
        return self._read(name)

    def _read(self, name: str) -> RobotJob:
        ns = self.namespace
        body = self._call("get", JOBS, lambda: self._api().get_namespaced_custom_object(
            GROUP, VERSION, ns, JOBS, name), namespace=ns, name=name)
        return RobotJob.model_validate(body)

    # ---- jobs
    def submit(self, spec: JobSpec, *, namespace: Optional[str] = None,
               name: Optional[str] = None, follow: bool = False) -> Job:
        """Create the RobotJob for ``spec``; the returned ``Job.id`` is its (maybe generated) name.

        ``follow=True`` declares that this client follows the job (annotation
        ``armnet.io/follower-timeout-seconds``): unless ``spec.detach``, the node
        agent cancels it when the heartbeats of :meth:`logs` stop for
        ``follower_timeout_s``. Without it nothing watches the job, as for
        ``kubectl apply``. Heartbeats need NATS: declare a follower only with a
        NATS URL configured (``execute`` and ``armnet submit`` do so).
        """
        ns = namespace or self.namespace
        body = robotjob_body(spec, namespace=ns, name=name,
                             follower_window_s=self.follower_timeout_s if follow else None)
        created = self._call("create", JOBS, lambda: self._api().create_namespaced_custom_object(
            GROUP, VERSION, ns, JOBS, body), namespace=ns)
        job = job_from_robotjob(RobotJob.model_validate(created))
        log.info("submitted robotjob %s/%s", ns, job.id)
        return job

    def get(self, name: str) -> Job:
        return job_from_robotjob(self._read(name))

    def describe(self, name: str) -> JobView:
        """The job with its queue position, progress and rollout (what ``armnet get`` shows)."""
        return view_of(self._read(name))

    def list_jobs(self) -> list[RobotJob]:
        """The namespace's RobotJobs, oldest first (as ``kubectl get`` lists by name, we list by age).

        The apiserver lists a namespace that does not exist as empty: an empty list is
        checked, and :class:`NamespaceNotFound` says so when the caller may look.
        """
        ns = self.namespace
        found = self._call("list", JOBS, lambda: self._api().list_namespaced_custom_object(
            GROUP, VERSION, ns, JOBS), namespace=ns)
        jobs = [RobotJob.model_validate(item) for item in found.get("items", [])]
        if not jobs:
            self._require_namespace(ns)
        return sorted(jobs, key=lambda j: (j.metadata.creation_timestamp.isoformat()
                                           if j.metadata.creation_timestamp else "", j.metadata.name))

    def _require_namespace(self, ns: str) -> None:
        """:class:`NamespaceNotFound` if ``ns`` does not exist; a caller who may not read namespaces
        (a tenant, usually) is not told, as ``kubectl`` does not."""
        from kubernetes import client as kclient

        try:
            self._call("get", "namespaces", lambda: kclient.CoreV1Api(self._connect().api_client).read_namespace(ns),
                       namespace=None, name=ns)
        except Forbidden:
            pass

    def submit_manifest(self, manifest: dict[str, Any], *, namespace: Optional[str] = None,
                        follow: bool = False) -> Job:
        """Create a RobotJob manifest as written (``armnet submit -f``), in ``namespace`` if given.

        The body is validated against the client's model of the CRD first, so a
        typo fails here with the field's name rather than in the apiserver.
        """
        if manifest.get("kind") != "RobotJob":
            raise InvalidJob(f"expected kind RobotJob, got {manifest.get('kind')!r}")
        metadata = dict(manifest.get("metadata") or {})
        ns = namespace or metadata.get("namespace") or self.namespace
        metadata["namespace"] = ns
        if follow:
            declared = follower_metadata(bool((manifest.get("spec") or {}).get("detach")), self.follower_timeout_s)
            if declared:
                metadata["annotations"] = {**(metadata.get("annotations") or {}), **declared["annotations"]}
        body = {**manifest, "apiVersion": API_VERSION, "metadata": metadata}
        try:
            RobotJobSpec.model_validate(body.get("spec") or {})
        except ValidationError as exc:
            raise InvalidJob(f"the RobotJob's spec is not valid: {exc}") from exc
        if not metadata.get("name") and not metadata.get("generateName"):
            metadata["generateName"] = generated_name_prefix(str((body.get("spec") or {}).get("image", "")))
        created = self._call("create", JOBS, lambda: self._api().create_namespaced_custom_object(
            GROUP, VERSION, ns, JOBS, body), namespace=ns)
        return job_from_robotjob(RobotJob.model_validate(created))

    def cells(self) -> list[CellView]:
        found = self._call("list", CELLS, lambda: self._api().list_cluster_custom_object(
            GROUP, VERSION, CELLS), namespace=None)
        return sorted((cell_view_of(Cell.model_validate(i)) for i in found.get("items", [])),
                      key=lambda c: c.name)

    def quotas(self, *, all_tenants: bool = False) -> list[QuotaView]:
        """The CellQuotas of this client's namespace (every tenant's with ``all_tenants``), by name.

        CellQuotas are cluster-scoped: reading them takes the chart's cell-reader role
        (``rbac.tenants.cellReaderGroups``), as reading Cells does; without it the
        error says so (``Forbidden``).
        """
        found = self._call("list", CELLQUOTAS, lambda: self._api().list_cluster_custom_object(
            GROUP, VERSION, CELLQUOTAS), namespace=None)
        views = (quota_view_of(item) for item in found.get("items", []) if isinstance(item, Mapping))
        return sorted((v for v in views if all_tenants or v.tenant == self.namespace), key=lambda v: v.name)

    def cancel(self, name: str) -> Job:
        """Ask for the job to stop (``spec.cancel: true``): at once if queued, within the cell's grace if running."""
        ns = self.namespace
        patched = self._call("cancel", JOBS, lambda: self._api().patch_namespaced_custom_object(
            GROUP, VERSION, ns, JOBS, name, cancel_patch()), namespace=ns, name=name)
        return job_from_robotjob(RobotJob.model_validate(patched))

    def wait(self, name: str, timeout: Optional[float] = None) -> JobResult:
        """Poll the job's status until it is terminal and return its ``JobResult``.

        ``stdout``/``stderr`` are the whole output from the log stream when it
        can be read, else the status tails (the last 16 KiB each); an INFO line on
        the ``armnet_client`` logger says which. Raises :class:`WaitTimeout` after
        ``timeout`` seconds (the job keeps running).
        """
        job, result = self.wait_terminal(name, timeout)
        output = self._stream_output(job) if self.nats_url else None
        if output is None:
            log.info("robotjob %s: stdout/stderr are the status tails (last 16 KiB); "
                     "`armnet logs %s` has the whole output", name, name)
            return result
        log.info("robotjob %s: stdout/stderr are the whole output from the log stream", name)
        return result.model_copy(update={"stdout": output[0], "stderr": output[1]})

    def wait_terminal(self, name: str, timeout: Optional[float], *,
                      stored_output: bool = True) -> tuple[RobotJob, ClusterJobResult]:
        """Like :meth:`wait` but never reads the stream: the RobotJob and its result with the tails.

        A job preempted and requeued (``status.requeuedAs``) is followed to the job that runs it
        again: the result is the last run's, the RobotJob that one. A job whose output the node
        agent is still storing is waited for up to ``artifacts_wait_s`` more (and within ``timeout``),
        so that ``result.artifacts`` says where the output went; not with ``stored_output=False``.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            job = self._read(name)
            result = result_from_robotjob(job)
            successor = requeue_of(job) if result is not None else None
            if result is not None and successor is None:
                return self._with_stored_output(name, job, result, deadline) if stored_output else (job, result)
            if successor:
                log.info("robotjob %s was preempted; %s runs it again: waiting for that one", name, successor)
                name = successor
                continue
            if deadline is not None and time.monotonic() >= deadline:
                raise WaitTimeout(
                    f"robotjob {name!r} is still {job.status.phase or JobPhase.SUBMITTED} after {timeout:g} s; "
                    f"it keeps running: `armnet get {name}` or `armnet cancel {name}`"
                )
            time.sleep(self.poll_interval_s)

    def _with_stored_output(self, name: str, job: RobotJob, result: ClusterJobResult,
                            deadline: Optional[float]) -> tuple[RobotJob, ClusterJobResult]:
        """The ended job once its output settled (Uploaded, Failed, Discarded), or as it stands at the wait's end."""
        until = time.monotonic() + self.artifacts_wait_s
        if deadline is not None:
            until = min(until, deadline)
        said = False
        while result.artifacts is not None and result.artifacts.phase in ARTIFACTS_IN_PROGRESS:
            if time.monotonic() >= until:
                log.info("robotjob %s: its output is still %s; `armnet artifacts %s` says when it is stored",
                         name, result.artifacts.phase, name)
                break
            if not said:
                log.info("robotjob %s ended; waiting for the node agent to store its output", name)
                said = True
            time.sleep(self.poll_interval_s)
            try:
                fresh = self._read(name)
            except ClientError as exc:  # the result is in hand: an API hiccup or a delete does not lose it
                log.info("robotjob %s: its output's upload not followed further: %s", name, exc)
                break
            if fresh.metadata.uid != job.metadata.uid:
                break  # deleted and re-created under the name: another job's status from here
            job, result = fresh, result_from_robotjob(fresh) or result
        return job, result

    def _next_run(self, name: str) -> Optional[str]:
        """After a run's log stream ended: the job that runs it again if it was preempted and requeued."""
        while True:
            successor = requeue_of(self._read(name))
            if successor != "":
                return successor
            time.sleep(self.poll_interval_s)  # the operator creates the copy on its next pass

    def _stream_output(self, job: RobotJob) -> Optional[tuple[str, str]]:
        """The job's whole stdout and stderr from the stream; ``None`` when unreadable or empty."""
        assert self.nats_url is not None
        ns = job.metadata.namespace or self.namespace
        job_id = job.status.job_id or job.metadata.uid or ""
        streams: dict[str, list[str]] = {"stdout": [], "stderr": []}
        try:
            for event in follow_events(FollowSettings(self.nats_url, stream=self.stream), ns, job_id,
                                       follow=False):
                if isinstance(event, LogLine) and event.kind in streams:
                    streams[event.kind].append(event.text + "\n")
        except NatsUnreachable as exc:
            log.warning("%s; stdout/stderr are the status tails", exc)
            return None
        if not streams["stdout"] and not streams["stderr"]:
            return None
        return "".join(streams["stdout"]), "".join(streams["stderr"])

    def execute(self, spec: JobSpec, *, follow: bool = True, out: Optional[TextIO] = None,
                err: Optional[TextIO] = None) -> JobResult:
        """Submit ``spec``, print its output while it runs (``follow``), return its ``JobResult``.

        With ``follow`` and a reachable log stream, ``stdout``/``stderr`` of the
        result are the whole output read while following; otherwise as :meth:`wait`.
        """
        # Without NATS there are no heartbeats: declaring a follower would get the job cancelled.
        job = self.submit(spec, follow=follow and self.nats_url is not None)
        if not follow:
            return self.wait(job.id)
        stdout: list[str] = []
        stderr: list[str] = []
        from_stream = True
        name: Optional[str] = job.id
        while name:
            for line in self.logs(name, follow=True):
                from_stream = from_stream and line.source == "stream"
                if line.kind == "stdout":
                    stdout.append(line.text + "\n")
                    print(line.text, file=out or sys.stdout)
                elif line.kind == "stderr":
                    stderr.append(line.text + "\n")
                    print(line.text, file=err or sys.stderr)
                elif line.kind == "progress":
                    print(f"[progress] {line.text}", file=err or sys.stderr)
            last, name = name, self._next_run(name)
            if name:
                print(f"[armnet] {last} was preempted; {name} runs it again, in its place in the queue",
                      file=err or sys.stderr)
                stdout.clear()
                stderr.clear()
        _, result = self.wait_terminal(job.id, None)
        if from_stream and (stdout or stderr):
            log.info("robotjob %s: stdout/stderr are the whole output from the log stream", job.id)
            return result.model_copy(update={"stdout": "".join(stdout), "stderr": "".join(stderr)})
        log.info("robotjob %s: stdout/stderr are the status tails (last 16 KiB)", job.id)
        return result

    # ---- output
    def logs(self, name: str, follow: bool = True, *, since: Optional[datetime] = None) -> Iterator[LogLine]:
        """The job's output lines, from its first line; with ``follow``, live until it ends.

        Reads JetStream when a NATS URL is configured and reachable; otherwise
        says so once (a warning) and follows the job's status instead (progress,
        rollout, then the output tails when it ends). With ``follow`` the last
        line is the job's terminal status with why it ended (``LogLine.reason``),
        from the stream or, when the stream does not say, from the RobotJob.
        """
        for event in self.log_events(name, follow, since=since):
            if isinstance(event, LogLine):
                yield event

    def log_events(self, name: str, follow: bool = True, *,
                   since: Optional[datetime] = None) -> Iterator[Event]:
        """:meth:`logs` with the :class:`CaughtUp` marker (where the stored lines end and live ones begin)."""
        for batch in self.log_batches(name, follow, since=since):
            yield from batch

    def log_batches(self, name: str, follow: bool = True, *,
                    since: Optional[datetime] = None) -> Iterator[list[Event]]:
        """:meth:`log_events` a list at a time: what arrived together (a printer writes it out at once)."""
        job = self._read(name)
        ns = job.metadata.namespace or self.namespace
        job_id = job.status.job_id or job.metadata.uid or ""
        streamed = False
        if self.nats_url:
            # Following a non-detached job keeps it alive: the agent cancels it when beats stop.
            beats = (HeartbeatSender(self.nats_url, ns, job_id, self.heartbeat_interval_s).start()
                     if follow and not job.spec.detach else None)
            try:
                end: Optional[LogLine] = None
                for batch in follow_batches(
                    FollowSettings(self.nats_url, stream=self.stream), ns, job_id, follow=follow,
                    finished=self._finished_probe(name), since=since,
                ):
                    streamed = streamed or any(isinstance(event, LogLine) for event in batch)
                    if follow:
                        # The follow's last line is said below, with why the job ended.
                        ends = [e for e in batch if isinstance(e, LogLine) and e.terminal_phase]
                        if ends:
                            end = ends[-1]
                            batch = [e for e in batch if not (isinstance(e, LogLine) and e.terminal_phase)]
                    if batch:
                        yield batch
                if follow:
                    ending: list[Event] = list(self._ending(name, end))
                    if ending:
                        yield ending
                return
            except NatsUnreachable as exc:
                log.warning("%s; following the job's status instead (progress, then the last "
                            "16 KiB of output when it ends)", exc)
            finally:
                if beats is not None:
                    beats.stop()
        else:
            log.warning("no NATS URL configured (--nats-url or ARMNET_NATS_URL): following the job's "
                        "status instead (progress, then the last 16 KiB of output when it ends)")
        # Lines already delivered from the stream are not repeated from the tails.
        for event in status_events(lambda: self._read(name), follow=follow,
                                   interval_s=self.poll_interval_s, tails=not streamed):
            yield [event]

    def _ending(self, name: str, streamed: Optional[LogLine]) -> Iterator[LogLine]:
        """The job's end with why it ended: the stream's status message, else the RobotJob's.

        The stream may not say (a job the operator cancelled while queued never reached an
        agent; an older agent published no error): then ``status.result.error`` does.
        """
        if streamed is not None and (streamed.reason or streamed.terminal_phase == JobPhase.SUCCEEDED):
            yield streamed
            return
        try:
            written = ended(self._read(name))
        except ClientError as exc:
            log.debug("the job's end not read from its status: %s", exc)
            written = None
        chosen = written if written is not None and (written.reason or streamed is None) else streamed
        if chosen is not None:
            yield chosen

    def _finished_probe(self, name: str) -> Callable[[], bool]:
        """A check of the job's phase, at most once per poll interval (the follower asks often)."""
        last = [0.0, False]

        def finished() -> bool:
            now = time.monotonic()
            if now - float(last[0]) >= self.poll_interval_s:
                last[0] = now
                try:
                    last[1] = result_from_robotjob(self._read(name)) is not None
                except ClientError as exc:
                    log.debug("status probe failed: %s", exc)
            return bool(last[1])

        return finished


def _client(**kwargs: Any) -> Client:
    return Client(**kwargs)


def submit(spec: JobSpec, *, namespace: Optional[str] = None, name: Optional[str] = None) -> Job:
    return _client().submit(spec, namespace=namespace, name=name)


def get(name: str) -> Job:
    return _client().get(name)


def wait(name: str, timeout: Optional[float] = None) -> JobResult:
    return _client().wait(name, timeout=timeout)


def cancel(name: str) -> Job:
    return _client().cancel(name)


def execute(spec: JobSpec, *, follow: bool = True) -> JobResult:
    return _client().execute(spec, follow=follow)


def logs(name: str, follow: bool = True) -> Iterator[LogLine]:
    return _client().logs(name, follow=follow)


__all__ = ["CaughtUp", "Client", "cancel", "execute", "get", "logs", "submit", "wait"]
