"""The committed dependency lock (lock/): its pins, its declared exceptions, its inputs' digest.

lock/ holds one input file per environment (``<name>.in``), the overrides that are the
only exceptions to a dependency's own pins (``overrides.txt``), and what
``scripts/lock.sh`` compiles from them with uv: ``dev.txt`` (the developer and CI venv)
and one file per image (``runtime``, ``platform``, ``lerobot``), each compiled with
``dev.txt`` as constraints so every environment holds the same versions.

Pure functions over text, used by the suite (``pip check`` minus the declared
exceptions must be empty, in the venv and in every image) and by the image builds
(armnet_testbed.shipped_images: a lock's wheel folder is keyed by the lock file's hash).
``python -m armnet_testbed.lockfile`` prints the inputs' digest that scripts/lock.sh
records in lock/inputs.sha256, so the suite can tell when the lock is older than its inputs.
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
import tomllib
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
LOCK_DIR = REPO_ROOT / "lock"
OVERRIDES = LOCK_DIR / "overrides.txt"
INPUTS_DIGEST = LOCK_DIR / "inputs.sha256"
PYPROJECTS = ("pyproject.toml", "runtime/pyproject.toml")

_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;\\]+)", re.MULTILINE)
# pip check's two kinds of line (pip/_internal/commands/check.py).
_CONFLICT = re.compile(r"^(\S+) (\S+) has requirement ([A-Za-z0-9][A-Za-z0-9._-]*)")
_MISSING = re.compile(r"^(\S+) (\S+) requires ([A-Za-z0-9][A-Za-z0-9._-]*), which is not installed")


def normalize(name: str) -> str:
    """A distribution name as PEP 503 compares them (``Pillow`` == ``pillow``, ``a_b`` == ``a-b``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def pins(text: str) -> dict[str, str]:
    """``{name: version}`` of a compiled lock (``name==version`` lines; hashes and comments skipped)."""
    return {normalize(name): version for name, version in _PIN.findall(text)}


def lock_file(name: str) -> Path:
    """lock/<name>.txt, or an error saying how to add a lock for a new image."""
    path = LOCK_DIR / f"{name}.txt"
    if not path.is_file():
        raise FileNotFoundError(
            f"no lock {path}: add lock/{name}.in and its line in scripts/lock.sh, then run scripts/lock.sh")
    return path


def overridden(text: str) -> frozenset[str]:
    """The packages overrides.txt names: the only ones whose pins the lock may depart from."""
    return frozenset(pins(text))


def unexcused(pip_check_output: str, excused: frozenset[str]) -> list[str]:
    """pip check's complaints that the overrides do not declare.

    A line ``X has requirement P..., but you have P v`` is excused when P is overridden
    (the lock chose P's version on purpose); a missing requirement never is. Lines pip
    prints when all is well ("No broken requirements found.") are not complaints.
    """
    left = []
    for line in pip_check_output.splitlines():
        line = line.strip()
        if not line or line.startswith("No broken requirements"):
            continue
        conflict = _CONFLICT.match(line)
        if conflict and normalize(conflict.group(3)) in excused:
            continue
        left.append(line)
    return left


def inputs_digest(root: Path = REPO_ROOT) -> str:
    """What the lock is compiled from: the dependency tables of both pyproject files, every
    lock/*.in and overrides.txt. Other pyproject edits (tool settings) leave it unchanged."""
    digest = hashlib.sha256()
    for name in PYPROJECTS:
        project = tomllib.loads((root / name).read_text())["project"]
        deps = {"dependencies": project.get("dependencies", []),
                "optional-dependencies": project.get("optional-dependencies", {})}
        digest.update(f"{name}\n{json.dumps(deps, sort_keys=True)}\n".encode())
    for path in sorted((root / "lock").glob("*.in")) + [root / "lock" / "overrides.txt"]:
        digest.update(f"{path.name}\n".encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


if __name__ == "__main__":
    sys.stdout.write(inputs_digest() + "\n")
