"""Request failures the connector answers with a specific ``error_type``.

Each carries the wire ``error_type`` (runtime/PROTOCOL.md) and a message that
tells the job's author what happened and what to do.
"""

from __future__ import annotations

from typing import Any

MAX_ERROR_CHARS = 2000
"""Error text echoed to a client or a log line is cut here: a hostile job controls much
of it (names, values, exception messages of its own arguments)."""


def bounded(text: str, limit: int = MAX_ERROR_CHARS) -> str:
    """``text`` cut to ``limit`` characters, saying how much was cut."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}… ({len(text) - limit} more characters cut)"


class RequestError(Exception):
    """A request the connector refuses; the reply is ``{"ok": false, "error_type": ...}``."""

    def __init__(self, error_type: str, message: str, **extra: Any) -> None:
        super().__init__(message)
        self.error_type = error_type
        self.message = message
        self.extra = extra

    def reply(self) -> dict[str, Any]:
        return {"ok": False, "error": bounded(self.message), "error_type": self.error_type, **self.extra}


def protocol_error(message: str) -> RequestError:
    return RequestError("ProtocolError", message)


def not_allowed(message: str) -> RequestError:
    return RequestError("NotAllowed", message)


def failure_reply(exc: BaseException) -> dict[str, Any]:
    """The reply for an exception raised by a real LeRobot call: its type name and message."""
    if isinstance(exc, RequestError):
        return exc.reply()
    text = str(exc)
    if isinstance(exc, KeyError) and len(exc.args) == 1 and isinstance(exc.args[0], str):
        text = exc.args[0]  # str(KeyError) quotes its message; the SDK's KeyError adds its own
    message = bounded(text) or type(exc).__name__
    return {"ok": False, "error": message, "error_type": bounded(type(exc).__name__, 128)}
