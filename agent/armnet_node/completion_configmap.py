"""A classifier model a Cell names by ConfigMap, written to a file of the agent's before anything reads it.

A cell owner who trained a success classifier ships it as a ConfigMap in the platform's
namespace, the node agent's own (``kubectl -n armnet-system create configmap reach
--from-file=reach.onnx``), instead of copying a file onto every robot host. A tenant
cannot reach it: Cells are cluster-scoped and the namespace is the platform's. The
connector, and a job pod's sidecar, read files only, so the agent reads the ConfigMap's
key and writes its bytes to ``<state>/completion-models/<cell>/<sha256, first 32 hex digits>.onnx``, then
hands the Cell on with ``classifier.model`` set to that file: the checks
(``CompletionReady``), the launch (a pod's ``hostPath`` mount) and the connector are
those of a host file from there on.

The file is named by its content: a new version of the model lands beside the one a
running job's connector loaded, never under it (the newest ``KEEP`` files of a cell are
kept). The ConfigMap is read again at most every ``REFRESH_S`` seconds per cell, so an
edit reaches the cell within that, and the agent's passes (every few seconds) cost the
API server one GET per cell and period. A ConfigMap that is missing, lacks the key or
cannot be read leaves the Cell's classifier unresolved and says why (``problem``): the
Cell's ``CompletionReady`` is False with it, and no job launches on the cell. An API
server that does not answer changes nothing a model was written for already (the file
stays the cell's until the ConfigMap itself says otherwise), and a launch waits for the
next read (at most ``PENDING_LIMIT_S``) rather than fail the job; a read the agent is refused (its RBAC) is a problem
like a missing ConfigMap. A cell that leaves the node takes its files with it (``retain``).
"""

from __future__ import annotations

import errno
import hashlib
import logging
import os
import re
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import urllib3
from armnet_core.cell_completion import MAX_MODEL_BYTES, ConfigMapKeyRef

from armnet_node.kube import ConfigMapForbidden, ConfigMapKeyMissing, KubeError
from armnet_node.model import Cell, parse_cell

log = logging.getLogger(__name__)

REFRESH_S = 10.0
"""A cell's ConfigMap is read again at most this often: an edit reaches the cell within it."""
KEEP = 3
"""Model files kept per cell (the newest): a running job's connector may still be loading an older one."""
PENDING_LIMIT_S = 60.0
"""How long a launch waits for a model whose ConfigMap cannot be read just now before the job fails."""
_CELL_NAME = re.compile(r"^[a-z0-9]([-a-z0-9.]{0,251}[a-z0-9])?$")


class ConfigMapReader(Protocol):
    def read_config_map_key(self, namespace: str, name: str, key: str) -> bytes: ...


@dataclass(frozen=True)
class Written:
    """One read of a cell's ConfigMap: the model's file, or why there is none."""

    source: str
    path: str | None
    problem: str | None
    at: float
    #: The read failed for a reason of the API server's (not a missing ConfigMap or key): try again.
    transient: bool = False
    #: When the transient failures in a row began (``at`` for the first).
    failing_since: float = 0.0


class ConfigMapModels:
    """Resolves the Cells' ``classifier.modelFrom`` into model files; safe from the agent's and the heartbeats' threads.

    ``namespace``: where the ConfigMaps live (the agent's own; None when it has none,
    and then every such Cell says how to give it one). One lock per cell is held across
    a read and its write: the pass and the heartbeat never read one cell's ConfigMap
    twice at once, and an older read is never stored after a newer one.
    """

    def __init__(self, reader: ConfigMapReader, namespace: str | None, directory: Path, *,
                 refresh_s: float = REFRESH_S, clock: Callable[[], float] = time.monotonic) -> None:
        self._reader = reader
        self.namespace = namespace
        self.directory = directory
        self._refresh_s = refresh_s
        self._clock = clock
        self._lock = threading.Lock()
        self._cell_locks: dict[str, threading.Lock] = {}
        self._written: dict[str, tuple[ConfigMapKeyRef, Written]] = {}

    def resolve(self, cell: Cell) -> Cell:
        """``cell`` with its classifier reading the ConfigMap's model from a file, or unchanged (no ConfigMap,
        or none could be written: ``problem`` says why)."""
        completion = cell.completion
        classifier = completion.classifier if completion is not None else None
        if completion is None or classifier is None or classifier.model_from is None:
            with self._lock:
                self._written.pop(cell.name, None)
            return cell
        written = self._written_for(cell.name, classifier.model_from.config_map_key_ref)
        if written.path is None:
            return cell
        resolved = completion.model_copy(update={"classifier": classifier.with_model_file(written.path)})
        return replace(cell, completion=resolved)

    def _latest(self, cell: str) -> Written | None:
        with self._lock:
            entry = self._written.get(cell)
        return entry[1] if entry is not None else None

    def problem(self, cell: str) -> str | None:
        """Why the cell's model from a ConfigMap is not on this host (None: it is, or the cell names none)."""
        latest = self._latest(cell)
        return latest.problem if latest is not None else None

    def pending(self, cell: str) -> bool:
        """The cell's model could not be read for a reason that may pass (the API server away, a full disk),
        and none was written before: a launch waits for the next read rather than fail the job over a hiccup,
        for at most ``PENDING_LIMIT_S`` (then the job fails, saying why)."""
        latest = self._latest(cell)
        return (latest is not None and latest.path is None and latest.transient
                and self._clock() - latest.failing_since < PENDING_LIMIT_S)

    def source(self, cell: str) -> str | None:
        """"ConfigMap <ns>/<name>, key <key>" for a cell whose model comes from one (for messages), else None."""
        latest = self._latest(cell)
        return latest.source if latest is not None else None

    def retain(self, cells: Collection[str]) -> None:
        """Forget the cells not in ``cells`` (gone, or moved to another node), their model files too."""
        with self._lock:
            gone = [name for name in self._written if name not in cells]
            for name in gone:
                del self._written[name]
                self._cell_locks.pop(name, None)
        known = set(cells)
        try:
            folders = [f for f in self.directory.iterdir() if f.is_dir() and f.name not in known]
        except FileNotFoundError:
            return
        for folder in folders:
            shutil.rmtree(folder, ignore_errors=True)

    def _written_for(self, cell: str, ref: ConfigMapKeyRef) -> Written:
        with self._lock:
            cell_lock = self._cell_locks.setdefault(cell, threading.Lock())
        with cell_lock:
            with self._lock:
                entry = self._written.get(cell)
            known = entry[1] if entry is not None and entry[0] == ref else None  # another ref: read anew
            now = self._clock()
            if known is not None and now - known.at < self._refresh_s:
                return known
            written = self._write(cell, ref, now)
            if written.path is None and written.transient and known is not None and known.path is not None:
                # The API server did not answer: the model written before is still the ConfigMap's last word.
                log.warning("cell %s: %s; keeping the model written before", cell, written.problem)
                written = replace(known, at=now)
            elif written.transient:
                since = known.failing_since if known is not None and known.transient else now
                written = replace(written, failing_since=since)
            with self._lock:
                self._written[cell] = (ref, written)
            return written

    def _write(self, cell: str, ref: ConfigMapKeyRef, now: float) -> Written:
        namespace = self.namespace
        source = f"ConfigMap {namespace or '?'}/{ref.name}, key {ref.key}"
        if namespace is None:
            return Written(source, None, (
                f"the classifier's model is in ConfigMap {ref.name}, and this node agent knows no namespace to read "
                "ConfigMaps from: run it in a pod of the Helm chart (POD_NAMESPACE) or give --config-namespace"), now)
        if not _CELL_NAME.match(cell):
            return Written(source, None, f"cell name {cell[:64]!r} cannot name a directory", now)
        try:
            data = self._reader.read_config_map_key(namespace, ref.name, ref.key)
        except (ConfigMapKeyMissing, ConfigMapForbidden) as exc:
            return Written(source, None, str(exc), now)
        except (KubeError, OSError, urllib3.exceptions.HTTPError) as exc:  # the API server away: asked again
            return Written(source, None, f"{source} could not be read ({type(exc).__name__}: {str(exc)[:200]})",
                           now, transient=True)
        if not data:
            return Written(source, None, f"{source} is empty; put the .onnx model file's bytes there", now)
        if len(data) > MAX_MODEL_BYTES:
            return Written(source, None, f"{source} holds {len(data)} bytes, over the {MAX_MODEL_BYTES}-byte cap", now)
        try:
            path = self._store(cell, data)
        except OSError as exc:  # a full or failing disk may recover; a refused or read-only directory will not
            return Written(source, None, f"{source} could not be written to {self.directory / cell} ({exc})", now,
                           transient=exc.errno in (errno.ENOSPC, errno.EIO))
        return Written(source, str(path), None, now)

    def _store(self, cell: str, data: bytes) -> Path:
        """The model's file (written whole and synced, readable by every uid: a pod's connector runs as its own),
        and at most ``KEEP`` files of the cell. A file of that name whose bytes are not these (a write a power
        loss cut short) is written again."""
        folder = self.directory / cell  # HostPaths.completion_models_of(cell)
        folder.mkdir(parents=True, exist_ok=True)
        os.chmod(self.directory, 0o755)
        os.chmod(folder, 0o755)
        digest = hashlib.sha256(data).hexdigest()
        path = folder / f"{digest[:32]}.onnx"
        if not (path.is_file() and hashlib.sha256(path.read_bytes()).hexdigest() == digest):
            fd, partial = tempfile.mkstemp(dir=folder, prefix=".partial-")
            try:
                with os.fdopen(fd, "wb") as out:
                    out.write(data)
                    out.flush()
                    os.fsync(out.fileno())
                os.chmod(partial, 0o644)
                os.replace(partial, path)
            except BaseException:
                Path(partial).unlink(missing_ok=True)
                raise
            log.info("cell %s: classifier model written to %s (%d bytes)", cell, path, len(data))
        self._prune(folder, path)
        return path

    @staticmethod
    def _prune(folder: Path, current: Path) -> None:
        """Keep ``current`` and the newest ``KEEP - 1`` other models of the cell."""
        others: list[tuple[int, Path]] = []
        for model in folder.glob("*.onnx"):
            if model == current:
                continue
            try:
                others.append((model.stat().st_mtime_ns, model))
            except FileNotFoundError:
                continue
        for _, old in sorted(others, reverse=True)[KEEP - 1:]:
            old.unlink(missing_ok=True)


def resolved_cell(obj: dict[str, object], models: ConfigMapModels | None) -> Cell:
    """The API's Cell as the agent works with it: parsed, its classifier's model from a ConfigMap a file."""
    cell = parse_cell(obj)
    return cell if models is None else models.resolve(cell)
