"""Whether the files a cell's completion monitor reads on the robot host are usable, checked again only
when they change.

A classifier's model file and a judge's token file are the cell owner's, put on the
robot host by hand; the connector reads them while a job runs, where a bad one would
only cost the job its verdicts. The node agent's heartbeat asks every few seconds
(``CompletionReady``); loading a model costs milliseconds to seconds, so the answer is
kept for as long as the files are the same (``file_identity``: content and permissions)
and the Cell's settings are unchanged. The checks are the connector's own
(``classifier_scorer.model_problem``, ``service_scorer.read_token``): the cell is
judged by the code that will read its files; before them, each file must lie in one
of the agent's completion directories and be readable by the connector's uid.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from armnet_connector.classifier_scorer import model_problem
from armnet_connector.host_files import readable_by
from armnet_connector.service_scorer import ServiceScoreError, read_token
from armnet_core.cell_completion import (
    DEFAULT_COMPLETION_DIRS,
    CompletionConfig,
    host_files,
    outside_dirs,
)

FileIdentity = tuple[int, ...] | None


def file_identity(path: str) -> FileIdentity:
    """What the check's answer depends on in ``path``'s metadata, None when it cannot be stat'ed.

    Device, inode, size and mtime for the content; ctime, mode and owner for who may read
    it (the fix a ``chmod o+r`` message asks for changes only those).
    """
    try:
        info = os.stat(path)
    except OSError:
        return None
    return (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns, info.st_ctime_ns, info.st_mode,
            info.st_uid, info.st_gid)


def files_problem(completion: CompletionConfig, dirs: tuple[str, ...] = DEFAULT_COMPLETION_DIRS,
                  reader_uid: int | None = None, model_dirs: tuple[str, ...] = ()) -> str | None:
    """Why the monitor cannot use its host files (the model, the token file), None when it can.

    ``dirs``: where the agent lets a Cell point (``HostPaths.completion_dirs``); ``model_dirs``: where a
    classifier's model may lie besides (the agent's own copies of ConfigMaps' models: never a token file);
    ``reader_uid``: the uid the connector reads them as (a pod's sidecar), None when it
    is this process (the container launcher's in-process connector). Never raises: a
    check that fails in an unforeseen way is the problem it reports.
    """
    paths = host_files(completion)
    try:
        refused = outside_dirs(paths, (*dirs, *model_dirs) if completion.classifier is not None else dirs)
        if refused is not None:
            return refused
        if reader_uid is not None:
            for path in paths:
                unreadable = readable_by(path, reader_uid)
                if unreadable is not None:
                    return unreadable
        if completion.classifier is not None:
            return model_problem(completion.classifier)
        service = completion.service
        if service is not None and service.token_file is not None:
            read_token(service.token_file)
    except ServiceScoreError as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - a check's own failure faults the cell, never the heartbeat
        return f"checking {', '.join(paths)} failed ({type(exc).__name__}: {str(exc)[:200]})"
    return None


@dataclass
class CompletionFilesCheck:
    """The latest answer for one completion setting and the files it was given for."""

    dirs: tuple[str, ...] = DEFAULT_COMPLETION_DIRS
    reader_uid: int | None = None
    model_dirs: tuple[str, ...] = ()
    _key: tuple[CompletionConfig, tuple[FileIdentity, ...]] | None = None
    _problem: str | None = None
    checks: int = field(default=0)

    def problem(self, completion: CompletionConfig) -> str | None:
        key = (completion, tuple(file_identity(path) for path in host_files(completion)))
        if key != self._key:
            self._problem = files_problem(completion, self.dirs, self.reader_uid, self.model_dirs)
            self._key = key
            self.checks += 1
        return self._problem
