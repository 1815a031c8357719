"""The one error the test bed raises for a machine that is not set up."""

from __future__ import annotations

SETUP_HINT = "run scripts/setup.sh from the repository root (idempotent; cold ~25 min, warm seconds)"


class TestbedSetupError(RuntimeError):
    """A tool, binary or image the test bed needs is missing or does not start.

    Tests must fail (never skip) on this, with a message saying how to fix it.
    """

    __test__ = False  # not a pytest test class despite the name

    def __init__(self, what: str) -> None:
        super().__init__(f"{what}\n  -> {SETUP_HINT}")
