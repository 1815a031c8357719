"""Reading a file the cell owner put on the robot host (a classifier's model, a judge's token), safely.

The Cell names the path; the connector (and the node agent's check) read it with
their own rights, so the read refuses anything but a plain regular file at exactly
that path: a symbolic link anywhere on the way (the path must be its own real path),
a FIFO or device (``lstat`` before the open, so none is opened; opened non-blocking and
checked again with ``fstat`` to be the same file), and more than ``cap`` bytes (the read stops one byte past
it, so a file that grows meanwhile cannot fill the reader's memory).
"""

from __future__ import annotations

import os
import stat


class HostFileError(RuntimeError):
    """The file cannot be read as asked; the message names the file and what is wrong, never its content."""


def read_host_file(path: str, cap: int, what: str) -> bytes:
    """At most ``cap`` bytes of the regular file ``path``; ``what`` names it in errors ("the model file")."""
    if os.path.realpath(path) != path:
        raise HostFileError(f"{what} {path} is a symbolic link or lies under one; give the file's real path")
    try:
        seen = os.lstat(path)  # before the open: a device node is never opened (that can act on it)
    except FileNotFoundError:
        raise HostFileError(f"{what} {path} does not exist on this robot host") from None
    except OSError as exc:
        raise HostFileError(f"{what} {path} cannot be read ({exc.strerror or type(exc).__name__})") from None
    if not stat.S_ISREG(seen.st_mode):
        raise HostFileError(f"{what} {path} is not a regular file")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise HostFileError(f"{what} {path} does not exist on this robot host") from None
    except OSError as exc:
        raise HostFileError(f"{what} {path} cannot be read ({exc.strerror or type(exc).__name__})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or (info.st_dev, info.st_ino) != (seen.st_dev, seen.st_ino):
            raise HostFileError(f"{what} {path} changed while it was opened; try again once it is in place")
        if info.st_size > cap:
            raise HostFileError(f"{what} {path} is {_size(info.st_size)}, over the {_size(cap)} it may be")
        chunks: list[bytes] = []
        left = cap + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
    except OSError as exc:
        raise HostFileError(f"{what} {path} cannot be read ({exc.strerror or type(exc).__name__})") from None
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > cap:
        raise HostFileError(f"{what} {path} grew past {_size(cap)} while it was read")
    return data


def readable_by(path: str, uid: int) -> str | None:
    """Why a process of ``uid`` (no supplementary groups counted) cannot read ``path``, None if it can."""
    try:
        info = os.stat(path)
    except OSError:
        return None  # the read itself says why
    # The kernel asks the owner's class alone when the uid owns the file; else, without knowing
    # the reader's groups, only the others' class counts.
    owner = info.st_uid == uid
    if uid == 0 or (owner and info.st_mode & stat.S_IRUSR) or (not owner and info.st_mode & stat.S_IROTH):
        return None
    return (f"{path} is not readable by the connector's uid {uid} (mode {stat.filemode(info.st_mode)}, "
            f"owner {info.st_uid}); make it readable by others (chmod o+r) or owned by uid {uid}")


def _size(size: int) -> str:
    return f"{size / (1 << 20):,.0f} MiB" if size >= 1 << 20 else f"{size:,} bytes"


__all__ = ["HostFileError", "read_host_file", "readable_by"]
