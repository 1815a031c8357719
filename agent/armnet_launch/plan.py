"""What a launcher starts, as data: the customer container's spec. Pure, no engine.

Local runs and the node agent describe the job container the same way (image,
command, env, mounts, labels); the container-engine launcher
(``launch.container``) turns it into a Docker API call, and a Kubernetes-pod
launcher would turn the same spec into a pod.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from armnet_core.api import CELL_LABEL, JOB_UID_LABEL, MANAGED_BY_LABEL, NAME_LABEL, NAMESPACE_LABEL

#: Labels tying a container to its cell and job; the agent re-adopts containers by them.
LABEL_CELL = CELL_LABEL
LABEL_JOB_UID = JOB_UID_LABEL
LABEL_NAMESPACE = NAMESPACE_LABEL
LABEL_NAME = NAME_LABEL
LABEL_MANAGED_BY = MANAGED_BY_LABEL
MANAGED_BY_AGENT = "armnet-agent"

#: Linux caps one env string (name=value) at 32 pages (MAX_ARG_STRLEN).
MAX_ENV_STRING_BYTES = 128 * 1024


@dataclass(frozen=True)
class Mount:
    host: str
    inside: str
    read_only: bool = False


@dataclass(frozen=True)
class ContainerSpec:
    """One customer container; ``command`` None runs the image's own entrypoint and command."""

    image: str
    env: Mapping[str, str]
    command: tuple[str, ...] | None = None
    mounts: tuple[Mount, ...] = ()
    labels: Mapping[str, str] = field(default_factory=dict)
    name: str | None = None


def oversized_env(env: Mapping[str, str], limit: int = MAX_ENV_STRING_BYTES) -> list[str]:
    """Names of the variables the kernel would refuse (``E2BIG`` at exec): one string over ``limit``."""
    return sorted(name for name, value in env.items() if len(f"{name}={value}".encode()) + 1 > limit)
