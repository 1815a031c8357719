"""``StartStop``: the ``with``-statement half of every simulator piece that runs threads.

Buses, arms and cells each own something that must be stopped (a pty thread,
or several); each says how to start and stop it, and this base turns that into
a context manager so tests cannot leak a running pty on failure.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from types import TracebackType
from typing import Self


class StartStop(ABC):
    """``start()`` returns the started object; ``with obj:`` starts it and always stops it."""

    @abstractmethod
    def start(self) -> Self: ...

    @abstractmethod
    def stop(self) -> None: ...

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
