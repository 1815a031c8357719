"""One request line and its one reply line on a pod's connector sidecar socket.

The node agent reaches a pod's connector through two Unix sockets in the pod's
volume: the observer's (telemetry, rollout events) and ``agent.sock`` (the cell
operator's inputs). Both speak one JSON object per line, one reply per request.
What is shared lives here: reaching a socket whose path is longer than a Unix
address holds, and reading the reply whole by a deadline with a size cap (the one
framing, ``armnet_core.framing``), so that a sidecar that trickles a byte at a time
or sends without end holds the agent for no longer than its timeout.
"""

from __future__ import annotations

import os
import socket
import stat
import time
from pathlib import Path
from typing import Any

from armnet_core.framing import LineReader, LineTooLong
from armnet_runtime.wire import dumps_line, loads_json


def connect_long(sock: socket.socket, path: Path) -> None:
    """``sock.connect(path)`` for a path longer than a unix socket address holds (108 bytes).

    The kubelet's path of a pod's volume is longer than that (113 bytes with the
    default root). The directory is opened (``O_PATH``) and the socket reached
    through the short ``/proc/self/fd/<fd>/<name>``, which is safe from other
    threads (unlike a ``chdir``).
    The socket itself is opened ``O_NOFOLLOW`` and must be a socket: a symlink put in
    its place (by whoever could write into the volume) would otherwise lead the agent
    to another pod's observer under the same mounted directory, or the kubelet's.
    """
    directory = os.open(path.parent, os.O_PATH | os.O_DIRECTORY)
    try:
        target = os.open(path.name, os.O_PATH | os.O_NOFOLLOW, dir_fd=directory)
    finally:
        os.close(directory)
    try:
        if not stat.S_ISSOCK(os.fstat(target).st_mode):
            raise ConnectionRefusedError(f"{path} is not a socket (a symlink or a file put in its place?)")
        sock.connect(f"/proc/self/fd/{target}")
    finally:
        os.close(target)


def exchange(sock: socket.socket, request: dict[str, Any], deadline: float, max_bytes: int) -> Any:
    """Send ``request`` as one line and return the decoded reply line.

    The whole reply by ``deadline`` (``time.monotonic()``): ``TimeoutError`` past it,
    ``ConnectionError`` if the peer closes first, ``ValueError`` for a reply over
    ``max_bytes`` or not JSON (``RecursionError`` for JSON nested too deep).
    """
    sock.settimeout(max(deadline - time.monotonic(), 0.001))
    sock.sendall(dumps_line(request))
    reader = LineReader(sock, max_bytes)
    try:
        line = reader.next(deadline)
    except LineTooLong:
        raise ValueError(f"a reply over {max_bytes} bytes") from None
    except TimeoutError:
        raise TimeoutError("the reply did not arrive in time") from None
    if not line.endswith(b"\n"):
        raise ConnectionError("the connector closed the connection")
    if len(line) + reader.pending > max_bytes:  # the cap holds for all it sent, newline or not
        raise ValueError(f"a reply over {max_bytes} bytes")
    if reader.pending:
        raise ValueError("the connector sent more than one reply line")
    return loads_json(line)
