"""What the cell device plugin tells the kubelet: the resource name, the device's health, an allocation. Pure.

One extended resource per cell (``armnet.io/cell-<cell>``, capacity 1, one
device whose id is the cell's name): the connector sidecar of the cell's job
requests it, so the kubelet hands the cell's devices to that container alone.

How a device reaches the container decides whether it opens there:

- a real character device (a USB serial adapter ``/dev/ttyUSB0``, reached
  through its ``/dev/serial/by-id/...`` symlink, a camera ``/dev/video0``) is a
  ``DeviceSpec``: the runtime creates the node in the container and adds the
  device-cgroup rule for it, so no privileged container is needed;
- a simulated cell's pty (``/dev/pts/N``) cannot be a ``DeviceSpec``: a node
  made with ``mknod`` outside the devpts filesystem does not open (``EIO``: the
  kernel finds a pty through its devpts entry), so it is a bind ``Mount`` of the
  host's ``/dev/pts/N``; runc's default device rules allow ptys (major 136).

The facts (does the path exist, what does it resolve to, is it a character
device) are read by the caller (``deviceplugin.server``); nothing here does I/O.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from armnet_core.api import CELL_RESOURCE_PREFIX as RESOURCE_PREFIX
from armnet_launch.pod_spec import device_path

HEALTHY = "Healthy"
UNHEALTHY = "Unhealthy"
#: The devpts mount: a pty there is bind-mounted, never re-created with mknod.
PTS_DIR = "/dev/pts/"
#: Extended resource names are qualified names: the part after the slash is at most 63 characters.
_NAME_PART = re.compile(r"^[A-Za-z0-9]([-A-Za-z0-9_.]{0,61}[A-Za-z0-9])?$")


class AllocationRefused(ValueError):
    """The cell's devices cannot be given now (a path is missing or is no device); the message says which."""


@dataclass(frozen=True)
class DevicePath:
    """One device of a cell: where the connector finds it, and the path configured on the host."""

    container_path: str
    host_path: str
    #: What the person at the cell calls it ("arm left's serial port", "camera /dev/video0"): named in
    #: the Cell's HardwareReady and a lost job's error. Not part of the device's identity.
    name: str = field(default="", compare=False)

    @property
    def label(self) -> str:
        return self.name or self.container_path


@dataclass(frozen=True)
class DeviceFact:
    """What the host shows for one ``DevicePath`` right now (read by the caller)."""

    path: DevicePath
    #: ``realpath`` of the host path (symlinks such as ``/dev/serial/by-id/...`` resolved); None: missing.
    resolved: str | None
    is_char_device: bool


@dataclass(frozen=True)
class DeviceGrant:
    """A ``DeviceSpec``: the runtime creates the node and its device-cgroup rule."""

    container_path: str
    host_path: str
    permissions: str = "rw"


@dataclass(frozen=True)
class MountGrant:
    """A bind ``Mount`` of a host path (a pty keeps its devpts entry this way)."""

    container_path: str
    host_path: str
    read_only: bool = False


@dataclass(frozen=True)
class Allocation:
    devices: tuple[DeviceGrant, ...] = ()
    mounts: tuple[MountGrant, ...] = ()


def resource_name(cell: str) -> str:
    """``armnet.io/cell-<cell>``; ``ValueError`` when the name cannot be an extended resource's."""
    part = RESOURCE_PREFIX.split("/", 1)[1] + cell
    if not _NAME_PART.match(part):
        raise ValueError(
            f"cell {cell!r}: the resource name {RESOURCE_PREFIX}{cell} is not a valid extended resource name "
            "(at most 63 characters after 'armnet.io/', letters, digits, '-', '_', '.'); rename the cell "
            "or run the agent with --no-device-plugin (hostPath devices)"
        )
    return RESOURCE_PREFIX + cell


def socket_name(cell: str) -> str:
    """Our socket's file name in the kubelet's device-plugin directory (one per cell)."""
    return f"armnet-cell-{cell}.sock"


def cell_device_paths(arms: Mapping[str, str | None], cameras: Sequence[int | str] = ()) -> tuple[DevicePath, ...]:
    """The devices of a cell: each arm's serial port at ``/dev/armnet/<arm>``, each camera at its own path.

    A camera configured by index ``N`` is ``/dev/videoN``; by path, the same path
    inside the container, so the connector's camera configuration holds as it is.
    An arm without a port is a device that can never be healthy (the Cell says no port).
    """
    paths = [DevicePath(device_path(arm), port or "", f"arm {arm}'s serial port") for arm, port in sorted(arms.items())]
    for camera in cameras:
        path = f"/dev/video{camera}" if isinstance(camera, int) else camera
        paths.append(DevicePath(path, path, f"camera {camera}"))
    return tuple(paths)


def problem(fact: DeviceFact) -> str | None:
    """Why this device cannot be given to a container now, or None."""
    if not fact.path.host_path:
        return f"no host path configured for {fact.path.container_path}"
    if fact.resolved is None:
        return f"{fact.path.host_path} does not exist"
    if not fact.is_char_device:
        return f"{fact.path.host_path} ({fact.resolved}) is not a character device"
    return None


def health(facts: Sequence[DeviceFact]) -> str:
    """``Healthy`` while every device of the cell is there (a cell without devices is not)."""
    if not facts or any(problem(fact) is not None for fact in facts):
        return UNHEALTHY
    return HEALTHY


def grant(fact: DeviceFact) -> DeviceGrant | MountGrant:
    """How one present device reaches the container (see the module docstring for why)."""
    reason = problem(fact)
    if reason is not None:
        raise AllocationRefused(reason)
    assert fact.resolved is not None
    if fact.resolved.startswith(PTS_DIR):
        return MountGrant(fact.path.container_path, fact.resolved)
    return DeviceGrant(fact.path.container_path, fact.resolved)


def allocate(facts: Sequence[DeviceFact]) -> Allocation:
    """Every device of the cell, or :class:`AllocationRefused` naming each missing one."""
    reasons = [reason for reason in map(problem, facts) if reason is not None]
    if not facts:
        reasons.append("the cell has no device (no port is known yet)")
    if reasons:
        raise AllocationRefused("; ".join(reasons))
    grants = [grant(fact) for fact in facts]
    return Allocation(
        devices=tuple(g for g in grants if isinstance(g, DeviceGrant)),
        mounts=tuple(g for g in grants if isinstance(g, MountGrant)),
    )
