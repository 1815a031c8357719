"""Repository-wide pytest configuration: the test bed's fixtures (real services)."""

pytest_plugins = ["armnet_testbed.plugin"]
