"""Container images without a registry: the debootstrap base and images built on it.

``build_image`` builds an ``images/*`` Containerfile through the Docker API with a
build context holding, in ``wheels/``, this repository's wheels (``armnet_runtime``
and ``armnet``, built ``--no-deps``) plus every dependency wheel they need, so a
Containerfile installs offline:

    ARG PIP_NO_INDEX PIP_FIND_LINKS      # build_image sets them to 1 and /tmp/wheels
    COPY wheels/ /tmp/wheels/
    RUN pip install /tmp/wheels/armnet_runtime-*.whl

(``pip install --no-index --find-links /tmp/wheels ...`` does the same without ARGs.)
The dependency wheels are cached under ~/.cache/armnet/wheelhouse by a hash of the
pyproject files; they are built with the host's pip, which reaches PyPI; the image
build itself needs no network.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tests.testbed.errors import TestbedSetupError
from tests.testbed.procs import progress

REPO_ROOT = Path(__file__).resolve().parents[2]
BASE_IMAGE = "localhost/armnet-base:bookworm"
WHEEL_CACHE = Path(os.environ.get("ARMNET_WHEELHOUSE", Path.home() / ".cache/armnet/wheelhouse"))
CONTAINER_WHEEL_DIR = "/tmp/wheels"


def require_base_image(client: Any) -> str:
    """The base image's id, or a setup error if scripts/setup.d/40-base-image.sh never ran."""
    import docker

    try:
        return str(client.images.get(BASE_IMAGE).id)
    except docker.errors.ImageNotFound as exc:
        raise TestbedSetupError(f"container base image {BASE_IMAGE} is not in podman") from exc


def _pip(*args: str) -> None:
    argv = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", *args]
    result = subprocess.run(argv, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} failed:\n{result.stdout}\n{result.stderr}")


_SKIP = shutil.ignore_patterns("build", "dist", "*.egg-info", "__pycache__", "*.pyc", ".*")
# What the root distribution is built from (see [tool.setuptools] in pyproject.toml).
_ROOT_SOURCES = ("pyproject.toml", "README.md", "operator", "agent", "cli")


def build_wheels(dest: Path) -> list[Path]:
    """This repository's two wheels (runtime/ and the root), no dependencies, into ``dest``.

    Built from a temporary copy of the sources: setuptools writes build/ and
    *.egg-info next to the sources, which would race between parallel sessions.
    """
    dest.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="armnet-wheels-") as tmp:
        runtime = Path(tmp) / "runtime"
        shutil.copytree(REPO_ROOT / "runtime", runtime, ignore=_SKIP)
        root = Path(tmp) / "root"
        root.mkdir()
        for name in _ROOT_SOURCES:
            source = REPO_ROOT / name
            if source.is_dir():
                shutil.copytree(source, root / name, ignore=_SKIP)
            elif source.is_file():
                shutil.copy2(source, root / name)
        _pip("wheel", "--no-deps", "--no-build-isolation", "-w", str(dest), str(runtime), str(root))
    return sorted(dest.glob("*.whl"))


def _dependency_wheelhouse(own_wheels: list[Path]) -> Path:
    """All dependency wheels of ``own_wheels``, cached by the pyproject files' content."""
    digest = hashlib.sha256()
    for f in (REPO_ROOT / "pyproject.toml", REPO_ROOT / "runtime" / "pyproject.toml"):
        digest.update(f.read_bytes())
    digest.update(f"{sys.version_info[:2]}".encode())
    house = WHEEL_CACHE / digest.hexdigest()[:16]
    stamp = house / ".complete"
    if not stamp.exists():
        started = time.monotonic()
        progress(f"building the dependency wheelhouse {house} (cold: a minute or two)")
        house.mkdir(parents=True, exist_ok=True)
        links = own_wheels[0].parent
        _pip("wheel", "-w", str(house), "--find-links", str(links), "--find-links", str(house),
             "-c", _constraints(), *[str(w) for w in own_wheels])
        for own in own_wheels:  # ours are rebuilt every time; keep only dependencies here
            (house / own.name).unlink(missing_ok=True)
        stamp.touch()
        progress(f"wheelhouse ready in {time.monotonic() - started:.0f} s")
    return house


def _constraints() -> str:
    # Never let a dependency drag in CUDA torch (see scripts/setup.d/10-python.sh).
    path = WHEEL_CACHE / "constraints.txt"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("torch==2.13.0\n")
    return str(path)


def prepare_context(containerfile: Path, dest: Path, *, with_dependencies: bool = True) -> Path:
    """Copy the Containerfile's directory to ``dest`` and add ``wheels/``; returns the file."""
    source_dir = containerfile.parent
    shutil.copytree(source_dir, dest, dirs_exist_ok=True)
    wheels = build_wheels(dest / "wheels")
    if with_dependencies:
        house = _dependency_wheelhouse(wheels)
        for wheel in house.glob("*.whl"):
            target = dest / "wheels" / wheel.name
            if not target.exists():
                try:
                    os.link(wheel, target)
                except OSError:
                    shutil.copy2(wheel, target)
    return dest / containerfile.name


def build_image(containerfile_dir_or_path: str | Path, tag: str, *, client: Any,
                base_image: str = BASE_IMAGE, with_dependencies: bool = True,
                buildargs: dict[str, str] | None = None) -> Any:
    """Build an image FROM the base image with this repo's wheels in the context.

    ``containerfile_dir_or_path`` is a directory holding ``Containerfile`` (e.g.
    ``images/runtime``) or the file itself. Returns the ``docker`` Image.
    """
    path = Path(containerfile_dir_or_path)
    if not path.is_absolute():
        path = REPO_ROOT / path
    containerfile = path / "Containerfile" if path.is_dir() else path
    if not containerfile.is_file():
        raise FileNotFoundError(f"no Containerfile at {containerfile}")
    require_base_image(client)
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="armnet-build-") as tmp:
        context = Path(tmp) / "context"
        cf = prepare_context(containerfile, context, with_dependencies=with_dependencies)
        args = {"BASE": base_image, "PIP_FIND_LINKS": CONTAINER_WHEEL_DIR,
                **({"PIP_NO_INDEX": "1"} if with_dependencies else {}), **(buildargs or {})}
        progress(f"building image {tag} from {containerfile.relative_to(REPO_ROOT) if containerfile.is_relative_to(REPO_ROOT) else containerfile}")
        import docker

        try:
            image, _logs = client.images.build(
                path=str(context), dockerfile=cf.name, tag=tag, buildargs=args, rm=True,
                forcerm=True, network_mode="host",
            )
        except docker.errors.BuildError as exc:
            lines = [str(c.get("stream", c.get("error", ""))).rstrip() for c in exc.build_log]
            raise RuntimeError(f"building {tag} failed: {exc.msg}\n" + "\n".join(lines[-40:])) from exc
    progress(f"built {tag} in {time.monotonic() - started:.1f} s")
    return image
