"""The walk of a job's output directory: bounded, and nothing in it can lead outside it.

The directory was written by the tenant's program, so every entry is hostile until
checked: entries are ``lstat``-ed, never followed blindly; a symbolic link is kept only
when its target is a regular file inside the directory (it is stored under the link's
name), and a link to a directory is not descended (no loops, no escape); FIFOs, sockets
and devices are left out (opening a FIFO would block the agent). The walk counts every
entry and every byte and stops at the first one over :class:`OutputLimits`, so 10^5
tiny files cost the agent one bounded pass and a clear error, not an upload.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from armnet_core.cell_record import CELL_RECORD

from armnet_node.artifacts.keys import name_refusal, printable
from armnet_node.artifacts.model import LocalFile, OutputLimits, OutputTooLarge, Refused, Scan

LINK_OUT = "a symbolic link that leads out of the output directory (not followed)"
LINK_TO_DIRECTORY = "a symbolic link to a directory (not followed)"
NOT_A_FILE = "not a regular file (a FIFO, socket or device)"
#: The connector writes each file of the record under ``.<name>.partial`` and renames it whole.
PARTIAL_SUFFIX = ".partial"
RESERVED = "a name reserved for the cell's record of the job (armnet-cell/): rename it"


def scan_job_output(output: Path | None, record: Path | None, limits: OutputLimits, prefix: str = "") -> Scan:
    """The job's output and, under ``armnet-cell/``, the cell's record of the job, as one scan.

    The job's directory may not hold a top-level ``armnet-cell`` of its own (left out, with
    the reason): a job must not pass its files off as the cell's. Each is walked within
    ``limits`` on its own (the record is the connector's, bounded by its writers: docs/connector.md;
    a file it is still writing is not stored). ``output`` None:
    the record alone (the job's output was over the cap).
    """
    job = (scan_output(output, limits, prefix, reserved=frozenset({CELL_RECORD})) if output is not None
           else Scan(files=(), refused=()))
    if record is None:
        return job
    cell = scan_output(record, limits, prefix, under=CELL_RECORD, skip_partial=True)
    return Scan(files=tuple(sorted((*job.files, *cell.files), key=lambda f: f.path)),
                refused=tuple(sorted((*job.refused, *cell.refused), key=lambda r: r.path)))


def scan_output(root: Path, limits: OutputLimits, prefix: str = "", *, reserved: frozenset[str] = frozenset(),
                under: str = "", skip_partial: bool = False) -> Scan:
    """The files under ``root`` to upload and the entries left out; :class:`OutputTooLarge` over a cap.

    ``prefix`` is the job's key prefix, for the key-length check. A missing ``root``
    (the job wrote nothing, or it was never created) is an empty scan. A top-level entry
    named in ``reserved`` is left out; ``under`` is put before every path found.
    ``skip_partial``: files a writer is still writing under a temporary name
    (``.<name>.partial``, the connector's) are not stored, silently: the whole file is,
    once renamed.
    """
    try:
        top = root.resolve(strict=True)
    except FileNotFoundError:
        return Scan(files=(), refused=())
    files: list[LocalFile] = []
    refused: list[Refused] = []
    entries = 0
    total = 0
    pending: list[tuple[str, Path]] = [(under, top)]
    while pending:
        rel_dir, directory = pending.pop()
        with os.scandir(directory) as listing:
            for entry in listing:
                entries += 1
                if entries > limits.max_files:
                    raise OutputTooLarge(
                        f"the job's output directory holds more than {limits.max_files} entries (files, "
                        "directories and links); nothing was uploaded. Write fewer, larger files (an archive, "
                        "a dataset's own chunked format) or ask the cell's operator for a higher cap"
                    )
                if skip_partial and entry.name.startswith(".") and entry.name.endswith(PARTIAL_SUFFIX):
                    continue
                path = f"{rel_dir}/{entry.name}" if rel_dir else entry.name
                # Case-blind: a download onto a case-insensitive disk would merge Armnet-Cell/ into armnet-cell/.
                why = (RESERVED if rel_dir == under and entry.name.casefold() in reserved
                       else name_refusal(prefix, path))
                if why is not None:
                    refused.append(Refused(printable(path), why))
                    continue
                found = _classify(entry, path, top)
                if isinstance(found, Refused):
                    refused.append(found)
                elif isinstance(found, LocalFile):
                    total += found.size
                    if total > limits.max_bytes:
                        raise OutputTooLarge(
                            f"the job's output directory holds more than {limits.max_bytes} bytes; nothing was "
                            "uploaded. Keep the output under the cap (compress, drop caches such as model "
                            "downloads) or ask the cell's operator for a higher cap"
                        )
                    files.append(found)
                else:
                    pending.append((path, Path(entry.path)))
    files.sort(key=lambda f: f.path)
    refused.sort(key=lambda r: r.path)
    return Scan(files=tuple(files), refused=tuple(refused))


def _classify(entry: os.DirEntry[str], path: str, top: Path) -> LocalFile | Refused | None:
    """A file to upload, an entry left out, or None for a directory to descend into."""
    info = entry.stat(follow_symlinks=False)
    if stat.S_ISDIR(info.st_mode):
        return None
    if stat.S_ISREG(info.st_mode):
        return LocalFile(path, Path(entry.path), info.st_size, info.st_mtime_ns)
    if not stat.S_ISLNK(info.st_mode):
        return Refused(path, NOT_A_FILE)
    target = Path(os.path.realpath(entry.path))
    if not target.is_relative_to(top):
        return Refused(path, LINK_OUT)
    try:
        pointed = target.stat()
    except OSError:
        return Refused(path, "a symbolic link to nothing")
    if stat.S_ISDIR(pointed.st_mode):
        return Refused(path, LINK_TO_DIRECTORY)
    if not stat.S_ISREG(pointed.st_mode):
        return Refused(path, NOT_A_FILE)
    return LocalFile(path, target, pointed.st_size, pointed.st_mtime_ns)
