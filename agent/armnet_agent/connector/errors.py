"""Request failures the connector answers with a specific ``error_type``.

Each carries the wire ``error_type`` (runtime/PROTOCOL.md) and a message that
tells the job's author what happened and what to do.
"""

from __future__ import annotations

from typing import Any


class RequestError(Exception):
    """A request the connector refuses; the reply is ``{"ok": false, "error_type": ...}``."""

    def __init__(self, error_type: str, message: str, **extra: Any) -> None:
        super().__init__(message)
        self.error_type = error_type
        self.message = message
        self.extra = extra

    def reply(self) -> dict[str, Any]:
        return {"ok": False, "error": self.message, "error_type": self.error_type, **self.extra}


def protocol_error(message: str) -> RequestError:
    return RequestError("ProtocolError", message)


def not_allowed(message: str) -> RequestError:
    return RequestError("NotAllowed", message)


def failure_reply(exc: BaseException) -> dict[str, Any]:
    """The reply for an exception raised by a real LeRobot call: its type name and message."""
    if isinstance(exc, RequestError):
        return exc.reply()
    message = str(exc) or type(exc).__name__
    return {"ok": False, "error": message, "error_type": type(exc).__name__}
