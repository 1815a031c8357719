"""Run a callback right after a named module has been imported, without importing it.

Why: a job should pay for LeRobot (and through it torch, pandas, datasets: seconds of
CPU) only when the job itself imports LeRobot. The SDK's LeRobot swap and the cell's
camera configs both need LeRobot's modules, so instead of importing them before
``@main`` they ask to be called back when the job's own import of the module ends.

:func:`when_imported` puts one finder at the front of ``sys.meta_path``. For a watched
name it asks the other finders for the real spec and wraps its loader, so the callback
runs after the module's code has run and before the importer gets the module back: no
other module can have bound a name from it yet. Every other import passes through
untouched (one dict lookup).
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import logging
import sys
import threading
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any, Optional

logger = logging.getLogger("armnet_runtime.lerobot")

ModuleCallback = Callable[[ModuleType], None]

_lock = threading.Lock()
_pending: dict[str, list[ModuleCallback]] = {}
"""Module name -> callbacks still waiting for that module's import to end."""


def when_imported(module_name: str, callback: ModuleCallback) -> None:
    """Call ``callback(module)`` once ``module_name`` is imported (now, if it already is).

    The callback runs in the importing thread, after the module's code and before the
    import statement returns. An exception in it is logged and never fails the import:
    the job's own import must behave as it would without armnet.
    """
    module = sys.modules.get(module_name)
    if module is not None:
        _call(callback, module)
        return
    with _lock:
        _pending.setdefault(module_name, []).append(callback)
        if not any(isinstance(finder, _WatchingFinder) for finder in sys.meta_path):
            sys.meta_path.insert(0, _WatchingFinder())


def watched() -> list[str]:
    """The module names whose import is still awaited (for logs and tests)."""
    with _lock:
        return sorted(_pending)


def _call(callback: ModuleCallback, module: ModuleType) -> None:
    try:
        callback(module)
    except Exception:  # noqa: BLE001 - a failing callback must not fail the job's import
        logger.exception("armnet: a post-import step for %s failed", module.__name__)


def _imported(module: ModuleType) -> None:
    with _lock:
        callbacks = _pending.pop(module.__name__, [])
    for callback in callbacks:
        _call(callback, module)


class _WatchingFinder(importlib.abc.MetaPathFinder):
    """Finds nothing itself: wraps the loader of a watched module found by the others."""

    def find_spec(
        self, fullname: str, path: Optional[Sequence[str]], target: Optional[ModuleType] = None
    ) -> Optional[importlib.machinery.ModuleSpec]:
        if fullname not in _pending:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _CallbackLoader(spec.loader)
                return spec
        return None


class _CallbackLoader(importlib.abc.Loader):
    """The real loader, and the watched callbacks once its ``exec_module`` returns."""

    def __init__(self, loader: Any) -> None:
        self._loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> Optional[ModuleType]:
        created: Optional[ModuleType] = self._loader.create_module(spec)
        return created

    def exec_module(self, module: ModuleType) -> None:
        self._loader.exec_module(module)
        _imported(module)

    def __getattr__(self, name: str) -> Any:
        # get_source, get_filename, is_package, get_resource_reader: the real loader's.
        return getattr(self._loader, name)
