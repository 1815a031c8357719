"""``--file-durations=N``: the N test files that took longest, printed at the end of a session.

``--durations`` names single tests; balancing the suite's sessions (``side_groups`` in
scripts/test.sh) moves whole files, and a file's time is also its fixtures' (a module's
control plane, a bed's agent and images). A file's time here is the sum of its tests'
setup, call and teardown phases, so a module-scoped fixture counts where it ran.
"""

from __future__ import annotations

import pytest


class FileDurations:
    """Sums each test file's phases; prints the slowest files in the terminal summary."""

    def __init__(self, wanted: int) -> None:
        self.wanted = wanted
        self.totals: dict[str, float] = {}

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        path = report.nodeid.split("::", 1)[0]
        self.totals[path] = self.totals.get(path, 0.0) + report.duration

    def pytest_terminal_summary(self, terminalreporter: pytest.TerminalReporter) -> None:
        whole = sum(self.totals.values())
        if whole <= 0:
            return
        terminalreporter.write_sep("=", f"slowest {self.wanted} test files (of {whole:.0f} s in tests)")
        for path, seconds in sorted(self.totals.items(), key=lambda item: -item[1])[:self.wanted]:
            terminalreporter.write_line(f"{seconds:8.1f}s {seconds / whole:6.1%}  {path}")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--file-durations", type=int, default=0, metavar="N",
                     help="print the N test files that took longest (setup, call and teardown summed)")


def pytest_configure(config: pytest.Config) -> None:
    wanted = int(config.getoption("--file-durations"))
    if wanted > 0:
        config.pluginmanager.register(FileDurations(wanted), "armnet-file-durations")
