"""Container images without a registry: the debootstrap base, and this repository's wheels.

The images themselves (``images/*``) are built by ``armnet_testbed.shipped_images``,
once per content hash, from the wheels ``build_wheels`` makes and the locked
dependency wheels it caches under ``WHEEL_CACHE``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from armnet_testbed.errors import TestbedSetupError

REPO_ROOT = Path(__file__).resolve().parents[2]
BASE_IMAGE = "localhost/armnet-base:bookworm"
WHEEL_CACHE = Path(os.environ.get("ARMNET_WHEELHOUSE", Path.home() / ".cache/armnet/wheelhouse"))


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
