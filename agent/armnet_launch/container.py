"""Running the job in a container through the Docker API (Docker or Podman's service).

The container gets the same env as a local subprocess, the run directory
(sockets, calibration, cache, volume) bind-mounted at the same path so every
endpoint and path in the env stays valid, host networking, and explicit
ulimits (rootless Podman refuses the engine defaults on some hosts). A local
run mounts its script's directory read-only; the agent runs the image's own
command. It implements the supervisor's ``LaunchedJob``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import signal
import threading
import time
import weakref
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from armnet_core.api import JOB_ID_LABEL

from .cri_log import CriStreamDecoder, NotCriLog
from .log_recovery import DeliveredLines, missed_output
from .plan import ContainerSpec, Mount

log = logging.getLogger(__name__)

PODMAN_SOCKET = "/run/podman/podman.sock"
JOB_DIR_IN_CONTAINER = "/armnet-job"
PING_TIMEOUT_S = 10
ULIMITS = (("nofile", 4096, 16384), ("nproc", 4096, 32768))
FOLLOW_GRACE_S = 1.0
"""How long a followed log stream may stay open after the container exited."""
LOG_FILE_POLL_S = 0.05
"""How often the container's log file is looked at for new output while the job is quiet."""
LOG_FILE_SETTLE_S = 0.1
"""After the exit, the file is read to its end twice this far apart (conmon's last writes)."""
LOG_FILE_READ_BYTES = 1 << 20


class EngineUnavailable(RuntimeError):
    """No container engine answers; the message says how to get one."""


def engine_url(environ: Mapping[str, str] | None = None) -> str:
    """``DOCKER_HOST`` when set, else Podman's system service socket."""
    environ = os.environ if environ is None else environ
    return environ.get("DOCKER_HOST") or f"unix://{PODMAN_SOCKET}"


def connect_engine(url: str | None = None) -> Any:
    """A pinged ``docker.DockerClient``, or :class:`EngineUnavailable` with the fix."""
    import docker
    from docker.errors import DockerException

    target = url or engine_url()
    hint = (
        f"no container engine answers at {target}. Start one (Podman: "
        "`podman system service --time=0 unix:///run/podman/podman.sock &`, or Docker Engine) "
        "or set DOCKER_HOST; or drop --image to run the script as a local subprocess."
    )
    try:
        docker.DockerClient(base_url=target, timeout=PING_TIMEOUT_S).ping()
    except DockerException as exc:
        raise EngineUnavailable(f"{hint} ({exc})") from exc
    # No read timeout on the client that follows the job: a job may print nothing for
    # minutes, and a timed-out log stream would silently lose its result markers.
    return docker.DockerClient(base_url=target, timeout=None)


def container_command(script: Path) -> list[str]:
    return ["armnet-runtime", f"{JOB_DIR_IN_CONTAINER}/{script.name}"]


class ContainerJob:
    """One job container; stdout/stderr are followed as two log streams."""

    follow_grace_s = FOLLOW_GRACE_S
    #: The supervisor waits for these streams to end: they always do (a stalled follow is
    #: closed ``follow_grace_s`` after the exit), and re-reading a large finished log is
    #: one long call with no line in between (seen: over 15 s for 100,000 lines under load).
    drain_stall_s = None
    #: Read the engine's log file when it can (``False``: always the Docker API's follow).
    read_log_file = True

    def __init__(self, client: Any, container: Any) -> None:
        self._client = client
        self._container = container
        self._exit_code: int | None = None
        self._done = threading.Event()
        self._pidfd_lock = threading.Lock()
        self._pidfd = _open_pidfd(container)
        if self._pidfd is None:
            log.info("container %s: no pidfd of its init here (an engine on another host, a pid namespace "
                     "of the agent's own, or it already ended): its exit is waited for and its kill sent "
                     "through the engine (Podman 4.3's wait costs the engine about a core meanwhile)",
                     str(container.id)[:12])
        exit_watch: int | None = None
        try:
            self._log_file, why_not = _log_file(client, container)
            if self._log_file is None:
                log.info("following container %s's output through the engine API (slower, and an exit "
                         "burst may arrive out of order): %s", str(container.id)[:12], why_not)
            # The waiter gets a descriptor of its own: remove() may close the job's meanwhile.
            exit_watch = os.dup(self._pidfd) if self._pidfd is not None else None
            threading.Thread(target=self._wait, args=(exit_watch,), name="armnet-container-wait",
                             daemon=True).start()
        except BaseException:
            for fd in (exit_watch, self._pidfd):
                if fd is not None:
                    os.close(fd)
            raise

    @property
    def waits_on_pidfd(self) -> bool:
        """The exit is seen through a pidfd of the container's init (no engine CPU while the job runs)."""
        return self._pidfd is not None

    @classmethod
    def start(
        cls,
        client: Any,
        image: str,
        script: Path,
        env: Mapping[str, str],
        run_dir: Path,
        extra_mounts: Mapping[str, str] | None = None,
        writable_mounts: tuple[str, ...] = (),
    ) -> ContainerJob:
        """Create and start a local run's job container (the script mounted from the host).

        ``extra_mounts`` (host path -> container path, read-only) is for
        development images that take their Python environment from the host;
        ``writable_mounts`` are host directories mounted read-write at the same
        path (``armnet run --output``).
        """
        script = script.resolve()
        mounts = [Mount(str(run_dir), str(run_dir)), Mount(str(script.parent), JOB_DIR_IN_CONTAINER, read_only=True)]
        mounts += [Mount(host, inside, read_only=True) for host, inside in (extra_mounts or {}).items()]
        mounts += [Mount(path, path) for path in writable_mounts]
        spec = ContainerSpec(
            image=image,
            command=tuple(container_command(script)),
            env=dict(env),
            mounts=tuple(mounts),
            labels={JOB_ID_LABEL: env.get("ARMNET_JOB_ID", "")},
        )
        return cls.launch(client, spec)

    @classmethod
    def launch(cls, client: Any, spec: ContainerSpec) -> ContainerJob:
        """Create and start the container ``spec`` describes (the one path local runs and the agent share)."""
        from docker.types import Ulimit

        volumes = {m.host: {"bind": m.inside, "mode": "ro" if m.read_only else "rw"} for m in spec.mounts}
        container = client.containers.create(
            spec.image,
            command=list(spec.command) if spec.command is not None else None,
            environment=dict(spec.env),
            volumes=volumes,
            network_mode="host",
            ulimits=[Ulimit(name=name, soft=soft, hard=hard) for name, soft, hard in ULIMITS],
            labels=dict(spec.labels),
            name=spec.name,
            detach=True,
        )
        try:
            container.start()
            return cls(client, container)
        except Exception:
            _remove_quietly(container)
            raise

    @classmethod
    def adopt(cls, client: Any, container: Any) -> ContainerJob:
        """Follow a container started earlier (by a previous agent process): its logs from the start."""
        return cls(client, container)

    @property
    def log_file(self) -> Path | None:
        """The engine's log file this job's output is read from, or None (the Docker API's follow)."""
        return self._log_file

    @property
    def container_id(self) -> str:
        return str(self._container.id)

    @property
    def oom_killed(self) -> bool:
        """The engine killed the container for its memory limit (an infrastructure failure)."""
        try:
            self._container.reload()
            return bool(self._container.attrs.get("State", {}).get("OOMKilled"))
        except Exception:  # noqa: BLE001 - the container is gone: we cannot tell
            return False

    def _wait(self, exit_watch: int | None) -> None:
        """The container's exit code, asked of the engine only once its init process has ended.

        Why not the engine's wait alone: Podman 4.3's Docker API (Debian 12's) answers
        ``POST /containers/{id}/wait`` by polling the container's state in a loop, half a
        core to a core of the engine's CPU for as long as the job runs (podman#18150).
        With a pidfd of the container's init (the engine on this host) the wait blocks
        in the kernel until that process ends; the engine's wait then only reads the
        exit code conmon recorded. Without one (an engine elsewhere) the engine's wait
        is all there is.
        """
        try:
            if exit_watch is not None:
                _block_until_exited(exit_watch)
            status = self._container.wait()
            self._exit_code = int(status.get("StatusCode", -1))
        except Exception:  # noqa: BLE001 - the engine went away: report an unknown exit
            self._exit_code = -1
        finally:
            self._done.set()

    def _logs(self, stdout: bool) -> Iterator[bytes]:
        if self.read_log_file and self._log_file is not None:
            return self._follow_file(self._log_file, stdout)
        return self._follow_api(stdout)

    def _follow_file(self, path: Path, stdout: bool) -> Iterator[bytes]:
        """The stream's output read from the engine's log file, in order, to its end after the exit.

        The agent runs beside Podman, whose ``k8s-file`` driver writes every
        record of both streams to one file as the container prints it; reading
        that file is faster than the Docker API's follow and never skips. The
        file is read until the container has exited and two reads
        ``LOG_FILE_SETTLE_S`` apart find nothing new.
        """
        name = "stdout" if stdout else "stderr"
        decoder = CriStreamDecoder(name)
        delivered = False
        try:
            with open(path, "rb") as file:
                settled = False
                while True:
                    exited = self._done.is_set()
                    data = file.read(LOG_FILE_READ_BYTES)
                    if data:
                        settled = False
                        out = decoder.feed(data)
                        if out:
                            delivered = True
                            yield out
                        continue
                    if os.fstat(file.fileno()).st_size < file.tell():
                        # conmon truncates the file at ``log_size_max`` (not set by default): lines
                        # written before it were read; go on from the new start.
                        log.warning("the container's log file %s was truncated (log_size_max in "
                                    "containers.conf?); reading on from its start", path)
                        file.seek(0)
                        continue
                    if exited:
                        if settled:
                            break
                        settled = True
                        time.sleep(LOG_FILE_SETTLE_S)
                        continue
                    self._done.wait(LOG_FILE_POLL_S)
        except (OSError, NotCriLog) as exc:
            if delivered:
                log.error("reading the container's log file %s failed part way (%s); the %s after "
                          "that point is lost", path, exc, name)
                return
            log.warning("cannot read the container's log file %s (%s); following %s through the engine API",
                        path, exc, name)
            yield from self._follow_api(stdout)
            return
        rest = decoder.finish()
        if rest:
            yield rest

    def _follow_api(self, stdout: bool) -> Iterator[bytes]:
        """The stream's output as it comes, then whatever the follow missed.

        With Podman 4.3's Docker API a follow can drop stretches of output when
        the container exits while it is behind, or stay open after the exit; the
        job's last lines carry its result marker. So a follow still open
        ``follow_grace_s`` after the exit is closed, and once the container is
        gone its finished log is compared with what the follow delivered (see
        ``log_recovery``).
        """
        follow = self._container.logs(stdout=stdout, stderr=not stdout, stream=True, follow=True)
        ended = threading.Event()

        def close_when_stalled() -> None:
            self._done.wait()
            if not ended.wait(self.follow_grace_s):
                try:
                    follow.close()
                except Exception:  # noqa: BLE001 - already closed, or a transport that cannot cancel
                    log.debug("closing a stalled log follow failed", exc_info=True)

        threading.Thread(target=close_when_stalled, name="armnet-log-follow-guard", daemon=True).start()
        delivered = DeliveredLines()
        try:
            for chunk in follow:
                delivered.add(chunk)
                yield chunk
        except Exception:  # noqa: BLE001 - a stream closed under the reader; the finished log covers it
            log.debug("log follow ended with an error", exc_info=True)
        finally:
            ended.set()
        self._done.wait()
        try:
            finished = self._container.logs(stdout=stdout, stderr=not stdout)
        except Exception:  # noqa: BLE001 - the engine or the container is gone: the follow is all we have
            log.warning("could not read the finished log to check the followed one", exc_info=True)
            return
        missed = missed_output(finished, delivered)
        if missed:
            log.info("the log follow missed %d bytes of %s; delivered from the finished log",
                     len(missed), "stdout" if stdout else "stderr")
            yield missed

    def stdout_chunks(self) -> Iterator[bytes]:
        return self._logs(stdout=True)

    def stderr_chunks(self) -> Iterator[bytes]:
        return self._logs(stdout=False)

    def wait(self, timeout: float) -> int | None:
        return self._exit_code if self._done.wait(max(timeout, 0.0)) else None

    def kill(self) -> None:
        """SIGKILL now: through a pidfd of the container's init when the engine is on this host.

        A loaded engine can take seconds to answer a kill request; the grace window
        promises the kill within a second. The pidfd cannot hit a recycled pid. The
        engine is asked too (it also covers an engine on another host), without waiting
        for it when the signal was already sent.
        """
        sent = False
        with self._pidfd_lock:
            if self._pidfd is not None:
                try:
                    signal.pidfd_send_signal(self._pidfd, signal.SIGKILL)
                    sent = True
                except OSError:
                    pass  # already exited
        if sent:
            threading.Thread(target=self._kill_via_engine, name="armnet-container-kill", daemon=True).start()
        else:
            self._kill_via_engine()

    def _kill_via_engine(self) -> None:
        from docker.errors import APIError

        try:
            self._container.kill(signal="SIGKILL")
        except APIError:
            pass  # already gone

    def remove(self) -> None:
        with self._pidfd_lock:
            if self._pidfd is not None:
                os.close(self._pidfd)
                self._pidfd = None
        _remove_quietly(self._container)


_ENGINE_KINDS: weakref.WeakKeyDictionary[Any, str] = weakref.WeakKeyDictionary()


def _engine_kind(client: Any) -> tuple[str | None, str]:
    """``"podman"`` or ``"other"`` for the engine behind ``client``, asked once per client.

    Why once: Podman answers ``/version`` by asking the host's package manager
    for each component's package (a ``dpkg-query`` per component), a cost every
    job paid; the engine behind one client does not change. A failure is not
    remembered: the next job asks again.
    """
    known = _ENGINE_KINDS.get(client)
    if known is not None:
        return known, ""
    try:
        components = client.version().get("Components") or []
    except Exception as exc:  # noqa: BLE001 - the API follow still works without it
        return None, str(exc)
    kind = "podman" if any("podman" in str(c.get("Name", "")).lower() for c in components) else "other"
    with contextlib.suppress(TypeError):  # a client that takes no weak reference is asked every time
        _ENGINE_KINDS[client] = kind
    return kind, ""


def _log_file(client: Any, container: Any) -> tuple[Path | None, str]:
    """The container's log file when it can be read here in the CRI format, else None and why.

    Podman's Docker API reports its ``k8s-file`` log as ``json-file``, so the
    engine is asked for its name: Docker's own json-file logs are another format.
    """
    kind, why_unknown = _engine_kind(client)
    if kind is None:
        return None, f"the engine's version is unknown ({why_unknown})"
    if kind != "podman":
        return None, "the engine is not Podman (its log file is not in the CRI format)"
    path = str(container.attrs.get("LogPath") or "")
    if not path:
        return None, "the engine reports no log file (a log driver other than k8s-file, e.g. journald)"
    if not os.access(path, os.R_OK):
        return None, f"the log file {path} is not readable here (the engine on another host, or another user's)"
    return Path(path), ""


def _open_pidfd(container: Any) -> int | None:
    """A pidfd of the container's init process, or None (engine elsewhere, exited, no pidfd support).

    The engine reports the pid in its own host's pid namespace: with an engine on
    another host (``DOCKER_HOST=tcp://...``) or an agent in a pid namespace of its
    own, that number names some unrelated process here, which a kill must never hit.
    So the pid is taken only when the process it names, once held by the pidfd, is
    in the container's cgroup.
    """
    try:
        container.reload()
        pid = int(container.attrs.get("State", {}).get("Pid") or 0)
    except Exception:  # noqa: BLE001 - the fast kill path is optional; the engine's kill remains
        return None
    return container_pidfd(pid, str(container.id))


def container_pidfd(pid: int, container_id: str) -> int | None:
    """A pidfd of process ``pid`` if it is, here and now, a process of container ``container_id``; else None.

    The cgroup is read after the pidfd is opened, and the pidfd is then checked to
    still hold a live process of that number: a live process had it all along, so the
    cgroup read was of the process the pidfd holds, not of a later one given the pid.
    """
    if pid <= 0:
        return None
    try:
        pidfd = os.pidfd_open(pid)
    except OSError:
        return None  # gone, or no pidfd support
    if process_in_container(pid, container_id) and _pidfd_holds(pidfd, pid):
        return pidfd
    os.close(pidfd)
    return None


def _pidfd_holds(pidfd: int, pid: int) -> bool:
    """Whether ``pidfd`` holds the live process ``pid`` (its fdinfo's ``Pid:`` line; -1 once it ended)."""
    try:
        info = Path(f"/proc/self/fdinfo/{pidfd}").read_text()
    except OSError:
        return False
    return any(line.split() == ["Pid:", str(pid)] for line in info.splitlines())


def process_in_container(pid: int, container_id: str) -> bool:
    """Whether process ``pid`` of this host is in the cgroup of container ``container_id``.

    Podman (``libpod-<id>``) and Docker (``docker-<id>.scope``, ``/docker/<id>``) name a
    container's cgroup after its full id, whatever the cgroup manager.
    """
    if len(container_id) < 32:
        return False  # a short or empty id would match too much
    try:
        groups = Path(f"/proc/{pid}/cgroup").read_text()
    except OSError:
        return False
    return container_id in groups


def _block_until_exited(pidfd: int) -> None:
    """Block, using no CPU, until the process behind ``pidfd`` has ended (a pidfd polls readable then); close it."""
    try:
        poller = select.poll()
        poller.register(pidfd, select.POLLIN)
        while not poller.poll():
            pass
    finally:
        os.close(pidfd)


def _remove_quietly(container: Any) -> None:
    from docker.errors import APIError

    try:
        container.remove(force=True)
    except APIError:
        pass  # already gone
