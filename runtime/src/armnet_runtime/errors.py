"""The SDK's error tree for talking to the connector.

Customer code catches these around hardware calls. ``RemoteAttributeError`` is an
``AttributeError`` so ``getattr(proxy, name, default)`` keeps Python semantics;
``ConnectorUnavailable`` is a ``ConnectionError`` so generic retry code works.
"""

from __future__ import annotations


class ConnectorError(RuntimeError):
    """Base of every error raised while talking to the cell's connector."""


class ConnectorUnavailable(ConnectorError, ConnectionError):
    """The connector endpoint could not be reached, or the connection broke mid-call."""


class ProtocolError(ConnectorError):
    """The peer did not speak the armnet connector protocol (see runtime/PROTOCOL.md)."""


class RemoteCallError(ConnectorError):
    """The connector refused or failed a request; ``error_type`` is the wire error type."""

    def __init__(self, message: str, error_type: str | None = None) -> None:
        super().__init__(message)
        self.error_type = error_type


class SafetyViolation(RemoteCallError):
    """A motion command exceeded the cell's safety limit; the cell tripped its interlock."""


class InterlockTripped(RemoteCallError):
    """The cell's interlock holds: motion is refused until the job ends."""


class ShuttingDown(RemoteCallError):
    """The job is past its deadline (the grace window): motion is refused, finish up and return."""


class RemoteAttributeError(AttributeError):
    """The remote object has no such public attribute (an ``AttributeError``, so defaults work)."""
