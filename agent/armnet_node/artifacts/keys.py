"""Object keys, name checks, the resume decision and the manifest document. Pure.

Layout of one job in the bucket::

    <namespace>/<job uid>/files/<path in the output directory>
    <namespace>/<job uid>/manifest.json      (written last: its presence means the upload finished)

Files live under ``files/`` so nothing a job writes can take the manifest's key. The
namespace and uid are checked against Kubernetes' own syntax, so a prefix can never
reach another namespace's objects.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Sequence

from armnet_core.output_keys import MANIFEST_NAME

from armnet_node.artifacts.model import Artifact, Refused

FILES_DIR = "files"
MANIFEST_VERSION = 1
#: S3 refuses keys over 1024 bytes (UTF-8).
MAX_KEY_BYTES = 1024
#: The object metadata entry holding a file's SHA-256 (hex); a resumed upload compares it.
SHA256_METADATA = "sha256"
#: At most this many refused entries are named in the manifest (the rest are counted).
MAX_REFUSED_LISTED = 200

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def manifest_key(prefix: str) -> str:
    return f"{prefix}{MANIFEST_NAME}"


def files_prefix(prefix: str) -> str:
    return f"{prefix}{FILES_DIR}/"


def object_key(prefix: str, path: str) -> str:
    """The key of the file at ``path`` (relative, ``/``-separated); call :func:`name_refusal` first."""
    return f"{files_prefix(prefix)}{path}"


def printable(path: str) -> str:
    """A path as text that can be shown and stored: undecodable bytes and controls as ``\\xNN``."""
    text = path.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)


def _encodes(path: str) -> bool:
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def name_refusal(prefix: str, path: str) -> str | None:
    """Why the file at ``path`` cannot become an object key, or None when it can.

    A key is refused when a client downloading it would write outside its target
    directory or misread it: a ``.``/``..``/empty segment, a name that is not UTF-8
    (the walk keeps undecodable bytes as surrogates), a control character, or a key
    over S3's 1024 bytes.
    """
    segments = path.split("/")
    if any(s in ("", ".", "..") for s in segments):
        return "a '.', '..' or empty path segment (a download could leave its directory)"
    if not _encodes(path):
        return "the name is not valid UTF-8"
    if _CONTROL.search(path):
        return "the name holds a control character"
    if len(object_key(prefix, path).encode("utf-8")) > MAX_KEY_BYTES:
        return f"the path is too long for an object key (over {MAX_KEY_BYTES} bytes with the job's prefix)"
    return None


def already_stored(size: int, sha256: str, stored_size: int | None, stored_sha256: str | None) -> bool:
    """Whether the stored object is this file: same size and the same SHA-256 in its metadata."""
    return stored_size == size and stored_sha256 is not None and stored_sha256 == sha256


def build_manifest(
    namespace: str, job_uid: str, artifacts: Sequence[Artifact], refused: Iterable[Refused],
    changed: Iterable[Refused],
) -> bytes:
    """The manifest object's body: every stored file with its checksum, and what was left out and why."""
    refused, changed = list(refused), list(changed)
    document = {
        "version": MANIFEST_VERSION,
        "namespace": namespace,
        "jobUid": job_uid,
        "complete": not changed,
        "files": [{"path": a.path, "key": a.key, "bytes": a.bytes, "sha256": a.sha256} for a in artifacts],
        "bytes": sum(a.bytes for a in artifacts),
        "refused": [{"path": r.path, "reason": r.reason} for r in refused[:MAX_REFUSED_LISTED]],
        "refusedCount": len(refused),
        "changed": [{"path": r.path, "reason": r.reason} for r in changed[:MAX_REFUSED_LISTED]],
        "changedCount": len(changed),
    }
    return json.dumps(document, indent=1, sort_keys=True).encode()
