"""The shipped images (images/runtime, images/operator, images/agent), built without a registry.

Each image's build context holds two wheel folders, so the Containerfiles install
offline and the big layer is built once:

- ``deps/``: the wheels of one committed lock, lock/<name>.txt (``deps/requirements.txt``,
  one ``name==version`` per wheel in the folder), fetched hash-checked and cached under
  ~/.cache/armnet/wheelhouse by the lock file's hash. Three locks, each compiled with the
  developer venv's lock as constraints (scripts/lock.sh), so an image holds the venv's
  versions: ``runtime`` (the SDK's closure), ``platform`` (the operator's: the root
  distribution's closure) and ``lerobot`` (the platform plus ``armnet-runtime[lerobot]``,
  LeRobot 0.4.4 with its dependencies; torch 2.13.0, a CUDA build that also runs on CPU,
  ~5 GB installed). The agent image and the runtime image's LeRobot variant use the same
  ``lerobot`` lock, so their dependency layer is one layer on a robot host.
- ``wheels/``: this repository's own wheels, rebuilt every time (small).

``ensure_image`` tags each build with a hash of everything that goes into it (the
Containerfile folder, the lock, the sources of our wheels, the base image id and the
build arguments) and skips the build when Podman has that tag: a warm test session
builds nothing. scripts/build-images.sh calls ``main`` to build all three for a real
registry (``--base python:3.11-slim``).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from armnet_testbed.images import BASE_IMAGE, REPO_ROOT, WHEEL_CACHE, build_wheels
from armnet_testbed.lockfile import lock_file
from armnet_testbed.procs import progress

HASH_LABEL = "armnet.io/content-hash"
LOCK_LABEL = "armnet.io/lock"
# Sources of our two wheels; a change in any of them is a new image. README.md goes into the
# root wheel's metadata only (its long description), so an edit there rebuilds nothing.
RUNTIME_SOURCES = ("runtime/pyproject.toml", "runtime/src")
PLATFORM_SOURCES = (*RUNTIME_SOURCES, "pyproject.toml", "operator", "agent", "cli", "fms")


@dataclass(frozen=True)
class ImageSpec:
    """One shipped image: which Containerfile, which lock, which of our wheels."""

    name: str
    containerfile_dir: str
    lock: str
    own: tuple[str, ...]
    buildargs: tuple[tuple[str, str], ...] = field(default=())

    @property
    def repository(self) -> str:
        return f"localhost/armnet-{self.name}"


RUNTIME = ImageSpec("runtime", "images/runtime", "runtime", ("armnet_runtime",))
RUNTIME_LEROBOT = ImageSpec("runtime-lerobot", "images/runtime", "lerobot", ("armnet_runtime",),
                            (("LEROBOT", "1"),))
OPERATOR = ImageSpec("operator", "images/operator", "platform", ("armnet_runtime", "armnet"))
AGENT = ImageSpec("agent", "images/agent", "lerobot", ("armnet_runtime", "armnet"))
ALL = {spec.name: spec for spec in (RUNTIME, RUNTIME_LEROBOT, OPERATOR, AGENT)}


# ---------------------------------------------------------------------- locks
def _lock_digest(lock: str) -> str:
    """What decides a lock's wheel folder: the lock file (pins and hashes) and the Python it is for."""
    digest = hashlib.sha256(lock_file(lock).read_bytes())
    digest.update(f"{sys.version_info[:2]}".encode())
    return digest.hexdigest()[:16]


def _pip(*args: str) -> None:
    argv = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", *args]
    result = subprocess.run(argv, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")


def lock_dir(lock: str) -> Path:
    """The wheel folder of lock/<lock>.txt with its requirements.txt; built once (network: PyPI).

    Every file is checked against the lock's hashes as it is downloaded (``--require-hashes``);
    the two dependencies published only as source (feetech-servo-sdk, evdev) are built into
    wheels here from their hash-checked archives, so the image builds compile nothing.
    """
    house = WHEEL_CACHE / f"lock-{lock}-{_lock_digest(lock)}"
    stamp = house / ".complete"
    if stamp.exists():
        return house
    started = time.monotonic()
    progress(f"building the {lock} dependency lock {house} (cold: minutes; lerobot: ~4 GB)")
    shutil.rmtree(house, ignore_errors=True)
    house.mkdir(parents=True)
    _pip("wheel", "-w", str(house), "--require-hashes", "--no-deps", "-r", str(lock_file(lock)))
    (house / "requirements.txt").write_text("".join(
        f"{requirement(wheel)}\n" for wheel in sorted(house.glob("*.whl"))))
    stamp.touch()
    progress(f"{lock} lock ready in {time.monotonic() - started:.0f} s")
    _drop_older_locks(house)
    return house


def _drop_older_locks(current: Path) -> None:
    """Remove this lock's folders for other dependency sets (a LeRobot lock is ~3 GB; kept
    after each dependency change, they would fill the disk across sessions)."""
    prefix = current.name.rsplit("-", 1)[0] + "-"
    for older in current.parent.glob(prefix + "*"):
        if older != current and older.is_dir():
            shutil.rmtree(older, ignore_errors=True)


def requirement(wheel: Path) -> str:
    """``name==version`` of a wheel file (PEP 427 file name)."""
    name, version = wheel.name.split("-")[:2]
    return f"{name}=={version}"


# ---------------------------------------------------------------------- content hash
def _hash_tree(digest: Any, path: Path) -> None:
    files = [path] if path.is_file() else sorted(
        p for p in path.rglob("*") if p.is_file() and "__pycache__" not in p.parts
        and not p.name.endswith(".pyc") and ".egg-info" not in str(p))
    for f in files:
        digest.update(str(f.relative_to(REPO_ROOT)).encode())
        digest.update(f.read_bytes())


def content_hash(spec: ImageSpec, base_id: str, buildargs: dict[str, str]) -> str:
    """What the image is made of: a change in any input is a different tag."""
    digest = hashlib.sha256()
    _hash_tree(digest, REPO_ROOT / spec.containerfile_dir)
    sources = PLATFORM_SOURCES if "armnet" in spec.own else RUNTIME_SOURCES
    for source in sources:
        _hash_tree(digest, REPO_ROOT / source)
    digest.update(f"{spec.lock} {_lock_digest(spec.lock)} {base_id}".encode())
    digest.update(repr(sorted(buildargs.items())).encode())
    return digest.hexdigest()[:12]


# ---------------------------------------------------------------------- build
def _revision() -> str:
    result = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"],
                            capture_output=True, text=True, check=False)
    return result.stdout.strip() or "unknown"


def ensure_image(spec: ImageSpec, *, client: Any, base_image: str = BASE_IMAGE,
                 version: str = "0.1.0") -> str:
    """The image's content-hash tag, built now only if Podman does not have it yet."""
    import docker

    try:
        base_id = str(client.images.get(base_image).id)
    except docker.errors.ImageNotFound:
        if base_image.startswith("localhost/"):
            raise
        base_id = str(client.images.pull(base_image).id)
    args = {"BASE": base_image, **dict(spec.buildargs)}
    tag = f"{spec.repository}:{content_hash(spec, base_id, args)}"
    try:
        client.images.get(tag)
        return tag
    except docker.errors.ImageNotFound:
        pass
    # The earlier builds are stale now: free their space before this build needs it (a
    # ~6 GB agent image commits its dependency layer through /var/tmp).
    lock_label = f"{spec.lock}-{_lock_digest(spec.lock)}"
    _drop_older_builds(client, spec.repository, keep="", lock=lock_label)
    _drop_stale_build_dirs()
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=f"armnet-{spec.name}-") as tmp:
        context = Path(tmp) / "context"
        shutil.copytree(REPO_ROOT / spec.containerfile_dir, context)
        own = [w for w in build_wheels(Path(tmp) / "all-wheels")
               if any(w.name.startswith(prefix + "-") for prefix in spec.own)]
        house = lock_dir(spec.lock)
        _link_all((context / "deps"), [*house.glob("*.whl"), house / "requirements.txt"])
        _link_all(context / "wheels", own)
        labels = {"VERSION": version, "REVISION": _revision(),
                  "CREATED": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        progress(f"building {tag} ({spec.containerfile_dir}, lock {spec.lock})")
        try:
            image, _logs = client.images.build(
                path=str(context), dockerfile="Containerfile", tag=tag, rm=True, forcerm=True,
                buildargs={**args, **labels, "LOCK": lock_label},
                labels={HASH_LABEL: tag.rsplit(":", 1)[1], LOCK_LABEL: lock_label},
                network_mode="none", timeout=3600,
            )
        except docker.errors.BuildError as exc:
            lines = [str(c.get("stream", c.get("error", ""))).rstrip() for c in exc.build_log]
            raise RuntimeError(f"building {tag} failed: {exc.msg}\n" + "\n".join(lines[-40:])) from exc
    image.tag(spec.repository, "dev")
    progress(f"built {tag} in {time.monotonic() - started:.0f} s")
    _drop_older_builds(client, spec.repository, keep=str(image.id), lock=lock_label)
    return tag


#: Podman's temporary build directories in /var/tmp (the context, the commit's blobs): a prefix and digits.
BUILD_TMP_NAME = re.compile(r"(libpod_builder|buildah|storage)\d+")
#: Older than this, a build directory is a leftover: our builds take minutes.
STALE_BUILD_DIR_S = 3 * 3600


def _drop_stale_build_dirs(tmp: Path = Path("/var/tmp"), now: float | None = None) -> list[Path]:
    """Remove Podman's build directories a failed or killed build left behind; return them.

    Why: a build that fails leaves its context (GBs with LeRobot's wheels) in /var/tmp for
    good (~2 GB each), and a LeRobot rebuild's peak leaves only a few GB of the disk free. Only directories untouched for hours go: a running build's are fresh.
    """
    now = time.time() if now is None else now
    removed = []
    for path in tmp.iterdir() if tmp.is_dir() else ():
        if not BUILD_TMP_NAME.fullmatch(path.name):
            continue
        try:
            if path.is_dir() and not path.is_symlink() and now - path.stat().st_mtime > STALE_BUILD_DIR_S:
                shutil.rmtree(path, ignore_errors=True)
                removed.append(path)
        except OSError:
            continue
    if removed:
        progress(f"removed {len(removed)} build directories a failed build left in {tmp}")
    return removed


def _drop_older_builds(client: Any, repository: str, *, keep: str, lock: str) -> None:
    """Remove this repository's earlier content-hash builds and the build's dangling stages.

    Why: each change to our sources is a new image, and the agent's is ~6 GB; a machine
    that runs the suite after every commit would otherwise fill its disk within a day.
    Only images this module tagged (the content-hash label) and untagged build leftovers
    older than a day are removed (younger stages are the layer cache the next build of a
    sibling image reuses: the agent and runtime-lerobot share their ~5 GB dependency
    stage); an image a container still uses stays (Podman refuses, and we go on). A stage
    labelled with another version of this build's lock (``LOCK_LABEL``: ``<lock>-<digest>``)
    is never reused, so it goes at once: a few lock changes would fill the disk. So does
    every image built on such a lock, whatever its repository: a lock change rebuilds all of
    them, and kept, the sibling built later (runtime-lerobot after the agent) and the test
    images made from it would hold the old ~5 GB dependency layers while the first one
    builds (a rebuild needs ~28 GB at its peak: docs/benchmarks.md).
    """
    import docker

    for image in client.images.list(name=repository, filters={"label": HASH_LABEL}):
        if image.id == keep:
            continue
        try:
            client.images.remove(image.id, force=True)
        except docker.errors.APIError as exc:
            progress(f"kept an earlier build of {repository} ({image.id[:19]}): {exc}")
    name = lock.rsplit("-", 1)[0] + "-"
    images = client.images.list(all=True, filters={"label": LOCK_LABEL})
    stale = {image.id: (str((image.labels or {}).get(LOCK_LABEL, "")), tuple(image.tags)) for image in images}
    stale = {image_id: (held, tags) for image_id, (held, tags) in stale.items()
             if held.startswith(name) and held != lock}
    while stale:  # children before their parents: a round removes what nothing else builds on
        refused: dict[str, tuple[str, tuple[str, ...]]] = {}
        for image_id, (held, tags) in stale.items():
            # Never forced: Podman's Docker API would remove a container still running on it.
            try:
                for ref in tags or (image_id,):
                    client.images.remove(ref)
            except docker.errors.ImageNotFound:
                pass
            except docker.errors.APIError as exc:
                refused[image_id] = (f"{held}: {exc}", tags)
        if len(refused) == len(stale):
            for image_id, (why, _) in refused.items():
                progress(f"kept an image of an earlier lock ({image_id[:19]}, {why})")
            break
        stale = {image_id: stale[image_id] for image_id in refused}
    try:
        client.images.prune(filters={"dangling": True, "until": "24h"})
    except docker.errors.APIError as exc:
        progress(f"could not prune dangling build stages: {exc}")


def _link_all(dest: Path, files: Iterable[Path]) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    for f in files:
        try:
            os.link(f, dest / f.name)
        except OSError:
            shutil.copy2(f, dest / f.name)


def image_size(client: Any, tag: str) -> int:
    return int(client.images.get(tag).attrs.get("Size", 0))


# ---------------------------------------------------------------------- CLI
def main(argv: Sequence[str] | None = None) -> int:
    """Build the shipped images and print their sizes (scripts/build-images.sh)."""
    import docker

    parser = argparse.ArgumentParser(prog="build-images", description=main.__doc__)
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"images to build, of {', '.join(sorted(ALL))} (default: runtime operator agent)")
    parser.add_argument("--base", default=BASE_IMAGE,
                        help="base image with python3 + venv (default: the test bed's debootstrap "
                             "base; for registries e.g. docker.io/library/python:3.11-slim)")
    parser.add_argument("--engine", default=os.environ.get("DOCKER_HOST", "unix:///run/podman/podman.sock"),
                        help="Docker API of the engine (default: DOCKER_HOST, else Podman's socket)")
    parser.add_argument("--version", default="0.1.0", help="org.opencontainers.image.version")
    args = parser.parse_args(argv)
    names = args.names or ["runtime", "operator", "agent"]
    unknown = sorted(set(names) - set(ALL))
    if unknown:
        parser.error(f"unknown image(s) {', '.join(unknown)}; choose from {', '.join(sorted(ALL))}")
    client = docker.DockerClient(base_url=args.engine, timeout=3600)
    built = [(name, ensure_image(ALL[name], client=client, base_image=args.base,
                                 version=args.version)) for name in names]
    print(f"{'image':<44} {'size':>10}")
    for _name, tag in built:
        print(f"{tag:<44} {image_size(client, tag) / 1e6:>8.0f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
