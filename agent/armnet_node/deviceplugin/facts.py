"""Reads what the host shows for a cell's device paths: the one read behind every device-health answer.

The device plugin (``deviceplugin.server``: ``ListAndWatch``, ``Allocate``) and
the agent's device watch (``node.device_watch``: the Cell's ``HardwareReady``,
a running job's "device lost") read device paths through this function only,
so they cannot disagree on what "present" means: the path resolves (symlinks
such as ``/dev/serial/by-id/...`` followed) and is a character device. No gRPC
here: the container-engine agent reads devices too.
"""

from __future__ import annotations

import os
import stat

from armnet_node.deviceplugin.decide import DeviceFact, DevicePath


def read_fact(path: DevicePath) -> DeviceFact:
    """What the host shows for one device path now (a symlink resolved)."""
    if not path.host_path:
        return DeviceFact(path, None, False)
    try:
        resolved = os.path.realpath(path.host_path, strict=True)
        mode = os.stat(resolved).st_mode
    except (OSError, ValueError):  # ValueError: a path the OS cannot take (a NUL byte in a Cell's port)
        return DeviceFact(path, None, False)
    return DeviceFact(path, resolved, stat.S_ISCHR(mode))
