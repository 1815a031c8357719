"""The camera proxy's frame reads: pixels from the connector's frame area, inline only as a fallback.

``read``, ``async_read`` and ``read_latest`` are real calls on the connector's
camera (so waiting, timeouts and errors are LeRobot's own); the reply names the
frame in a shared-memory area (``armnet_runtime.frames``) and the proxy copies it
out once into an ndarray the caller owns. When the two sides cannot share memory
(a TCP endpoint, an area this container cannot open) the proxy says so once in
the log and asks for the pixels inline from then on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armnet_runtime.endpoints import parse_endpoint
from armnet_runtime.errors import ProtocolError
from armnet_runtime.frames import FrameOverwritten, FrameReader
from armnet_runtime.wire import decode, encode

logger = logging.getLogger("armnet_runtime.lerobot")

DEFAULT_MAX_AGE_MS = 500
"""``OpenCVCamera.read_latest``'s default in LeRobot 0.4.4."""

OVERWRITTEN_RETRIES = 2
"""Calls repeated when a newer frame took the slot during the copy (only a many-threaded reader sees it)."""


def _frame_directory(endpoint: str) -> Path | None:
    try:
        address = parse_endpoint(endpoint)
    except ValueError:
        return None
    if address.scheme != "unix" or not address.path:
        return None
    return Path(address.path).parent


def _max_age_ms(args: tuple[Any, ...], kwargs: dict[str, Any]) -> float | None:
    """``read_latest``'s ``max_age_ms`` when the call binds plainly (else None: let the connector bind it)."""
    if len(args) + len(kwargs) > 1 or (kwargs and "max_age_ms" not in kwargs):
        return None
    value = args[0] if args else kwargs.get("max_age_ms", DEFAULT_MAX_AGE_MS)
    if type(value) not in (int, float):
        return None
    return float(value)


class FrameReads:
    """Mixin for ``RemoteObjectProxy`` cameras: the three frame reads through the frame area."""

    # Provided by RemoteObjectProxy (annotations only: the mixin comes first in the MRO).
    _endpoint: str
    _request: Callable[[dict[str, Any]], dict[str, Any]]

    def read(self, *args: Any, **kwargs: Any) -> Any:
        """Block until the next frame, as ``OpenCVCamera.read``."""
        return self._frame_call("read", args, kwargs)

    def async_read(self, *args: Any, **kwargs: Any) -> Any:
        """A frame newer than the last one this camera returned, within ``timeout_ms`` (default 200)."""
        return self._frame_call("async_read", args, kwargs)

    def read_latest(self, *args: Any, **kwargs: Any) -> Any:
        """The newest frame at once; ``TimeoutError`` when it is older than ``max_age_ms`` (default 500).

        Served from the frame area without a request while the connector marks the
        camera connected and its newest frame is young enough; in every other case
        the connector's camera answers (its error, or a frame that just arrived).
        """
        reader = self._frame_reader()
        if reader is not None:
            max_age = _max_age_ms(args, kwargs)
            if max_age is not None:
                frame = reader.latest(max_age)
                if frame is not None:
                    return frame
        return self._frame_call("read_latest", args, kwargs)

    def _frame_reader(self) -> FrameReader | None:
        state = self.__dict__
        if "_frames" not in state:
            directory = _frame_directory(self._endpoint)
            if directory is None:
                logger.info(
                    "%s: the connector at %s shares no directory with this process; frames travel inline",
                    type(self).__name__, self._endpoint,
                )
            state["_frames"] = FrameReader(directory) if directory is not None else None
        reader: FrameReader | None = state["_frames"]
        return reader

    def _frame_call(self, method: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> Any:
        payload = {"op": "call", "method": method, "args": [encode(a) for a in args], "kwargs": encode(kwargs)}
        for _ in range(1 + OVERWRITTEN_RETRIES):
            reader = self._frame_reader()
            reply = self._request({**payload, "frames": "shm" if reader is not None else "inline"})
            if "frame" not in reply:
                return decode(reply.get("value"))
            if reader is None:
                raise ProtocolError("the connector sent a frame descriptor to a proxy that asked for pixels inline")
            try:
                return reader.copy(reply["frame"])
            except FrameOverwritten:
                continue
            except OSError as exc:
                self._fall_back_inline(f"cannot map the frame area: {exc}")
        # Still overwritten (or just fell back): this call's pixels come inline.
        reply = self._request({**payload, "frames": "inline"})
        return decode(reply.get("value"))

    def _fall_back_inline(self, why: str) -> None:
        reader = self.__dict__.get("_frames")
        if reader is not None:
            reader.close()
        self.__dict__["_frames"] = None
        logger.warning(
            "%s: camera frames cannot go through shared memory (%s); they travel inline from now on, "
            "at a cost of milliseconds per frame. Mount the connector's socket directory into this container.",
            type(self).__name__, why,
        )
