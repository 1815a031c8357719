"""``--file-durations``: the suite's sessions print their slowest test files, fixtures included."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.unit
pytest_plugins = ["pytester"]


@pytest.fixture
def pytester(pytester: pytest.Pytester) -> pytest.Pytester:
    """The inner runs load the venv's plugins too: give pytest-asyncio the setting it warns about."""
    pytester.makeini("[pytest]\nasyncio_default_fixture_loop_scope = function\n")
    return pytester


def test_the_slowest_files_come_first_with_their_module_fixtures_counted(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        test_quick="def test_a():\n    pass\n",
        test_slow_fixture=(
            "import time, pytest\n"
            "@pytest.fixture(scope='module')\n"
            "def bed():\n    time.sleep(0.3)\n    yield\n"
            "def test_b(bed):\n    pass\n"
            "def test_c(bed):\n    pass\n"
        ),
    )
    result = pytester.runpytest("-p", "tests.support.file_durations", "--file-durations=5")
    result.assert_outcomes(passed=3)
    lines = result.outlines[result.outlines.index(next(line for line in result.outlines
                                                          if "slowest 5 test files" in line)) + 1:]
    files = [line.split()[-1] for line in lines if line.strip().endswith(".py")]
    assert files == ["test_slow_fixture.py", "test_quick.py"], result.outlines
    assert float(lines[0].split()[0].rstrip("s")) >= 0.3


def test_nothing_is_printed_without_the_option(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_one="def test_a():\n    pass\n")
    result = pytester.runpytest("-p", "tests.support.file_durations")
    result.assert_outcomes(passed=1)
    assert not any("test files" in line for line in result.outlines)
