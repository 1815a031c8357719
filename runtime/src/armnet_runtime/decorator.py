"""The ``@main`` decorator and its one-slot registry.

The ``armnet-runtime`` entrypoint imports the customer's script (which runs the
decorator as a side effect) and then asks :func:`registered_main` what to call.
A second ``@main`` is almost certainly a bug, so it raises instead of replacing
the first.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Optional

EntryPoint = Callable[..., Any]

_registered: Optional[EntryPoint] = None


class MainRegistrationError(RuntimeError):
    """Raised when ``@main`` is used incorrectly (multiple times, etc.)."""


def _describe(fn: EntryPoint) -> str:
    module = getattr(fn, "__module__", "?")
    name = getattr(fn, "__qualname__", repr(fn))
    return f"{module}.{name}"


def main(fn: EntryPoint) -> EntryPoint:
    """Mark ``fn`` as the script's entry point; it is called with a ``Context``.

    Its JSON-serialisable return value becomes ``JobResult.return_value``.
    """
    global _registered
    if _registered is not None:
        raise MainRegistrationError(
            "armnet: multiple @main-decorated functions found "
            f"(already registered: {_describe(_registered)}; new: {_describe(fn)}). "
            "Only one entry point per container is supported."
        )
    _registered = fn
    return fn


def registered_main() -> Optional[EntryPoint]:
    """Return the function previously registered with ``@main``, if any."""
    return _registered


def _clear_registration() -> None:
    """Forget the registered entry point (for tests and for re-running a script in-process)."""
    global _registered
    _registered = None
