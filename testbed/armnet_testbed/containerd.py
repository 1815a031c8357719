"""The test-bed node's containerd: its config, its persistent image store, and imports into it.

One containerd at a time runs on the store (``CONTAINERD_ROOT``, an image cache like
Podman's storage, so a warm start imports nothing): the node's (testbed/armnet_testbed/node.py, with
a kubelet) or, before any test session starts, setup's own (``import_into_store``,
scripts/setup.d/55-node-images.sh), which imports the images the sessions' pods run so
that no 6 GB ``podman save`` / ``ctr import`` runs beside timing-sensitive tests. Both
hold the host-wide node lock (``hold_node_lock``) while their containerd runs.

Images are imported without a registry (``podman save`` -> ``ctr images import``), each
labelled with the Podman image id it came from (``SOURCE_LABEL``): an image whose label
matches is not imported again.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.procs import ManagedProcess, progress, require_tool, wait_until

PAUSE_IMAGE = "localhost/armnet-pause:testbed"
CONTAINERD_ROOT = Path(os.environ.get("ARMNET_NODE_CONTAINERD_ROOT",
                                     Path.home() / ".cache/armnet/node/containerd"))
# Experiment override (testbed/armnet_testbed/node.py's docstring); unset by default.
CONTAINERD_ENV = "ARMNET_TESTBED_CONTAINERD"
# Label on an imported image: the Podman image id it came from (re-import on change).
SOURCE_LABEL = "armnet.io/podman-image-id"
LOCK_PATH = Path("/run/lock/armnet-testbed-node.lock")


# ---------------------------------------------------------------------- config files
def containerd_major(version_output: str) -> int:
    """The major version in ``containerd --version`` output.

    ``containerd github.com/containerd/containerd 1.6.20~ds1 ...`` -> 1,
    ``containerd github.com/containerd/containerd/v2 2.2.1+unknown`` -> 2.
    """
    fields = version_output.split()
    if len(fields) < 3 or not fields[2].lstrip("v").split(".")[0].isdigit():
        raise TestbedSetupError(f"unrecognised `containerd --version` output: {version_output!r}")
    return int(fields[2].lstrip("v").split(".")[0])


def containerd_root(major: int, *, overridden: bool, env: Mapping[str, str] | None = None) -> Path:
    """The persistent root: a containerd 2 from the override gets its own unless one is set."""
    if not overridden or major < 2 or "ARMNET_NODE_CONTAINERD_ROOT" in (os.environ if env is None else env):
        return CONTAINERD_ROOT
    return CONTAINERD_ROOT.with_name(f"{CONTAINERD_ROOT.name}-v{major}")


def containerd_config(workdir: Path, root: Path, cni_conf_dir: Path, *, major: int = 1,
                      shim: Path | None = None) -> str:
    """containerd's config: state under ``workdir``, CRI as docs/reference/testbed-host.md says.

    Schema 2 for containerd 1.6; for containerd 2 (``major``) the same settings in
    schema 3, with ``shim`` as the runc shim if given.
    """
    if major >= 2:
        return _containerd_config_v3(workdir, root, cni_conf_dir, shim)
    return f"""version = 2
root = "{root}"
state = "{workdir / 'state'}"
oom_score = 0
disabled_plugins = ["io.containerd.snapshotter.v1.aufs", "io.containerd.snapshotter.v1.btrfs",
  "io.containerd.snapshotter.v1.devmapper", "io.containerd.snapshotter.v1.zfs",
  "io.containerd.tracing.processor.v1.otlp", "io.containerd.internal.v1.tracing"]

{_sockets_and_opt(workdir)}  [plugins."io.containerd.grpc.v1.cri"]
    # Required here: without CAP_SYS_RESOURCE runc cannot apply the negative
    # oom_score_adj the kubelet asks for (every pod fails otherwise).
    restrict_oom_score_adj = true
    sandbox_image = "{PAUSE_IMAGE}"
    stream_server_address = "127.0.0.1"
    stream_server_port = "0"
    enable_selinux = false
    [plugins."io.containerd.grpc.v1.cri".cni]
      bin_dir = "/usr/lib/cni"
      conf_dir = "{cni_conf_dir}"
      max_conf_num = 1
    [plugins."io.containerd.grpc.v1.cri".containerd]
      snapshotter = "overlayfs"
      default_runtime_name = "runc"
      [plugins."io.containerd.grpc.v1.cri".containerd.runtimes.runc]
        runtime_type = "io.containerd.runc.v2"
        [plugins."io.containerd.grpc.v1.cri".containerd.runtimes.runc.options]
          SystemdCgroup = false
          Root = "{workdir / 'state' / 'runc'}"
"""


def _sockets_and_opt(workdir: Path) -> str:
    """The sections both schemas write alike: the sockets under ``workdir``, no debug or metrics, ``opt``."""
    return f"""[grpc]
  address = "{workdir / 'containerd.sock'}"

[ttrpc]
  address = "{workdir / 'containerd.sock.ttrpc'}"

[debug]
  address = ""

[metrics]
  address = ""

[plugins]
  [plugins."io.containerd.internal.v1.opt"]
    path = "{workdir / 'opt'}"
"""


def _containerd_config_v3(workdir: Path, root: Path, cni_conf_dir: Path, shim: Path | None) -> str:
    runtime = '[plugins."io.containerd.cri.v1.runtime".containerd.runtimes.runc]'
    return f"""version = 3
root = "{root}"
state = "{workdir / 'state'}"
oom_score = 0
# NRI would serve /var/run/nri/nri.sock and read /etc/nri; CDI reads /etc/cdi.
disabled_plugins = ["io.containerd.tracing.processor.v1.otlp", "io.containerd.internal.v1.tracing",
  "io.containerd.nri.v1.nri"]

{_sockets_and_opt(workdir)}  [plugins."io.containerd.cri.v1.images"]
    snapshotter = "overlayfs"
    [plugins."io.containerd.cri.v1.images".pinned_images]
      sandbox = "{PAUSE_IMAGE}"
  [plugins."io.containerd.cri.v1.runtime"]
    restrict_oom_score_adj = true
    enable_selinux = false
    enable_cdi = false
    [plugins."io.containerd.cri.v1.runtime".cni]
      bin_dirs = ["/usr/lib/cni"]
      conf_dir = "{cni_conf_dir}"
      max_conf_num = 1
    [plugins."io.containerd.cri.v1.runtime".containerd]
      default_runtime_name = "runc"
      {runtime}
        runtime_type = "io.containerd.runc.v2"
        runtime_path = "{shim or ''}"
        [plugins."io.containerd.cri.v1.runtime".containerd.runtimes.runc.options]
          SystemdCgroup = false
          Root = "{workdir / 'state' / 'runc'}"
  [plugins."io.containerd.grpc.v1.cri"]
    stream_server_address = "127.0.0.1"
    stream_server_port = "0"
"""


# ---------------------------------------------------------------------- processes
def proc_cmdline(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    except OSError:
        return []


def shim_pids(containerd_socket: Path) -> list[int]:
    """containerd-shim processes started by the containerd listening on ``containerd_socket``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            argv = proc_cmdline(int(entry.name))
            if argv and "containerd-shim" in argv[0] and str(containerd_socket) in argv:
                pids.append(int(entry.name))
    return pids


def hold_node_lock(timeout: float) -> TextIO:
    """The host-wide node lock (one test-bed node, or setup's import, at a time), held until closed.

    Waits up to ``timeout`` seconds for the holder to stop; the lock file says who holds it.
    """
    LOCK_PATH.parent.mkdir(parents=True, exist_ok=True)
    lock = open(LOCK_PATH, "a+")  # noqa: SIM115 - the caller closes it (release_node_lock)
    deadline = time.monotonic() + timeout
    announced = False
    while True:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() > deadline:
                lock.close()
                raise TimeoutError(
                    f"another test-bed node holds {LOCK_PATH} (see `cat {LOCK_PATH}`) "
                    f"for more than {timeout:.0f} s; stop it (armnet dev up / "
                    "a pytest session / scripts/setup.sh) and retry") from None
            if not announced:
                progress(f"waiting for another test-bed node to stop ({LOCK_PATH})")
                announced = True
            time.sleep(1)
    lock.seek(0)
    lock.truncate()
    lock.write(f"pid {os.getpid()}: {' '.join(proc_cmdline(os.getpid()))[:200]}\n")
    lock.flush()
    return lock


def release_node_lock(lock: TextIO) -> None:
    fcntl.flock(lock, fcntl.LOCK_UN)
    lock.close()


# ---------------------------------------------------------------------- images
def orphan_image_ids(listing: str) -> list[str]:
    """The ``sha256:<id>`` references in a ``ctr images ls`` listing whose target no named image has."""
    rows = [line.split() for line in listing.splitlines()[1:] if line.strip()]
    named_targets = {row[2] for row in rows if len(row) > 2 and not row[0].startswith("sha256:")}
    return [row[0] for row in rows if len(row) > 2 and row[0].startswith("sha256:") and row[2] not in named_targets]


# ---------------------------------------------------------------------- containerd
@dataclass
class Containerd:
    """One containerd on the persistent image store; its state, socket and log under ``workdir``."""

    workdir: Path
    root: Path = CONTAINERD_ROOT
    process: ManagedProcess | None = None
    socket: Path = field(init=False)
    log: Path = field(init=False)

    def __post_init__(self) -> None:
        self.socket = self.workdir / "containerd.sock"
        self.log = self.workdir / "containerd.log"

    def start(self, cni_conf_dir: Path,
              track: Callable[[ManagedProcess], None] = lambda _process: None) -> Containerd:
        """Start containerd and wait for its API; ``track`` learns the process before the wait."""
        binary = (require_tool("containerd", Path(os.environ[CONTAINERD_ENV]))
                  if os.environ.get(CONTAINERD_ENV) else require_tool("containerd"))
        require_tool("ctr")
        overridden = bool(os.environ.get(CONTAINERD_ENV))
        major = 1
        if overridden:
            major = containerd_major(subprocess.run([binary, "--version"], capture_output=True,
                                                    text=True, check=False).stdout)
        self.root = containerd_root(major, overridden=overridden)
        self.root.mkdir(parents=True, exist_ok=True)
        shim = Path(binary).parent / "containerd-shim-runc-v2"
        config = self.workdir / "containerd.toml"
        config.write_text(containerd_config(self.workdir, self.root, cni_conf_dir, major=major,
                                            shim=shim if overridden and shim.is_file() else None))
        started = time.monotonic()
        self.process = ManagedProcess("containerd", [binary, "--config", str(config)], self.log)
        track(self.process)
        wait_until(lambda: self.ctr("version", check=False).returncode == 0, timeout=30,
                   what="containerd", alive=self.process.ensure_running)
        progress(f"containerd up in {time.monotonic() - started:.1f} s")
        return self

    def stop(self) -> None:
        """Kill and delete every task and container, kill their shims, stop containerd; safe twice."""
        if self.process is None:
            return
        with contextlib.suppress(Exception):
            for task in self.running_tasks():
                self.ctr("tasks", "kill", "-s", "SIGKILL", task, check=False)
                self.ctr("tasks", "delete", "-f", task, check=False)
            for container in self.ctr("containers", "list", "-q", check=False).stdout.split():
                self.ctr("containers", "delete", container, check=False)
        for pid in shim_pids(self.socket):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        self.process.stop()
        self.process = None

    def running_tasks(self) -> list[str]:
        result = self.ctr("tasks", "list", "-q", check=False)
        return [t for t in result.stdout.split() if t] if result.returncode == 0 else []

    def ctr(self, *args: str, check: bool = True, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        """``ctr`` against this containerd, namespace ``k8s.io`` (the CRI's)."""
        argv = ["ctr", "--address", str(self.socket), "--namespace", "k8s.io", *args]
        result = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, check=False)
        if check and result.returncode:
            raise RuntimeError(f"{' '.join(argv)} failed: {result.stderr.strip()}")
        return result

    def import_images(self, *images: str) -> list[str]:
        """Import the images the store lacks in ONE archive; return those imported.

        Why one archive: the agent image and the runtime's LeRobot variant share a ~5 GB
        dependency layer. Saved one by one, each archive carries it and containerd unpacks
        it twice; a multi-image archive carries each layer once.
        """
        wanted: dict[str, str] = {}
        for image in images:
            inspect = subprocess.run(["podman", "image", "inspect", "--format", "{{.Id}}", image],
                                     capture_output=True, text=True, check=False)
            if inspect.returncode:
                raise TestbedSetupError(f"image {image} is not in podman: {inspect.stderr.strip()}")
            image_id = inspect.stdout.strip()
            if f"{SOURCE_LABEL}={image_id}" not in self.ctr("images", "ls", f"name=={image}").stdout:
                wanted[image] = image_id
        if not wanted:
            return []
        # The names' earlier images go first: the import needs room for the new one, its archive
        # and, unpacked, its snapshots (~20 GB for the agent), and the old one held ~13 GB of it.
        for image in wanted:
            self.ctr("images", "rm", "--sync", image, check=False)
        self.drop_unnamed_images()
        key = hashlib.sha256(" ".join(sorted(wanted)).encode()).hexdigest()[:12]
        archive = self.workdir / f"images-{key}.tar"
        started = time.monotonic()
        try:
            saved = subprocess.run(["podman", "save", "--multi-image-archive", "--format", "docker-archive",
                                    "-o", str(archive), *wanted], capture_output=True, text=True, check=False)
            if saved.returncode:
                raise RuntimeError(f"podman save {' '.join(wanted)} failed: {saved.stderr.strip()}")
            self.ctr("images", "import", str(archive), timeout=1200)
        finally:
            archive.unlink(missing_ok=True)
        for image, image_id in wanted.items():
            self.ctr("images", "label", image, f"{SOURCE_LABEL}={image_id}")
        progress(f"images: {', '.join(wanted)} imported in {time.monotonic() - started:.0f} s")
        return list(wanted)

    def drop_unnamed_images(self) -> list[str]:
        """Remove the CRI's image-id references that no named image shares any more; return them.

        The CRI names every image it sees by its id too (``sha256:<id>``). Re-importing or
        untagging a name leaves that reference holding the old image's content and snapshots
        for good: 12 GB per superseded agent image, until a build ran out of disk.
        """
        orphans = orphan_image_ids(self.ctr("images", "ls").stdout)
        for ref in orphans:
            self.ctr("images", "rm", "--sync", ref, check=False)  # --sync: the space is free on return
        return orphans

    def forget_images(self, stale: Callable[[str], bool]) -> list[str]:
        """Remove the named images ``stale`` picks, and the content only they held; return their names."""
        names = [name for name in self.ctr("images", "ls", "-q").stdout.split() if stale(name)]
        for name in names:
            self.ctr("images", "rm", name, check=False)
        self.drop_unnamed_images()
        return names


def import_into_store(images: Sequence[str], *, forget: Callable[[str], bool] = lambda _name: False,
                      lock_timeout: float = 600.0) -> list[str]:
    """Import ``images`` into the node's store with a containerd of our own (no kubelet); return those imported.

    For setup, before any test session starts: the node then starts with them in its cache.
    ``forget`` picks earlier images to remove first (superseded tags of the same repositories).
    """
    if os.geteuid() != 0:
        raise PermissionError("the test-bed node's image store belongs to root: run setup as root")
    lock = hold_node_lock(lock_timeout)
    workdir = Path(tempfile.mkdtemp(prefix="armnet-node-images-"))
    containerd = Containerd(workdir)
    try:
        (workdir / "cni").mkdir()
        containerd.start(workdir / "cni")
        forgotten = containerd.forget_images(forget)
        if forgotten:
            progress(f"images: removed the superseded {', '.join(forgotten)}")
        return containerd.import_images(*images)
    finally:
        containerd.stop()
        shutil.rmtree(workdir, ignore_errors=True)
        release_node_lock(lock)
