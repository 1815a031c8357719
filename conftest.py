"""Repository-wide pytest configuration: the test bed's fixtures (real services), and the
suite's per-file timing (``--file-durations``, which scripts/test.sh passes to every session)."""

pytest_plugins = ["armnet_testbed.plugin", "tests.support.file_durations"]
