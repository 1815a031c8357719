"""The connector's warm imports leave ``os.environ`` alone once ``import_before_threads`` ran.

numpy's first import before 2.4 sets ``OPENBLAS_MAIN_FREE`` and deletes it again. In the
node agent that import runs in the warm-imports thread while another thread walks
``os.environ`` (requests reads proxy settings from it on every Docker API call), and a
job then fails to launch with ``KeyError: 'OPENBLAS_MAIN_FREE'``. Each case runs in a
fresh interpreter (numpy is imported once per process), with the environment's store
replaced by one that records deletions, so the hazard shows deterministically rather than
in one run of many. numpy 2.4 (the lock's) sets and unsets that key with ``putenv``
instead of through ``os.environ`` (numpy gh-30627), so its import deletes nothing: the
guard stays for numpy releases before 2.4 and any other module that edits the environment.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.unit

RECORD_DELETIONS = textwrap.dedent(
    """
    import os, threading, time

    class Recording(dict):
        deleted = []
        def __delitem__(self, key):
            Recording.deleted.append(key.decode() if isinstance(key, bytes) else key)
            super().__delitem__(key)

    os.environ._data = Recording(os.environ._data)
    """
)


def run_fresh(body: str) -> str:
    env = {key: value for key, value in os.environ.items() if not key.endswith("_MAIN_FREE")}
    done = subprocess.run([sys.executable, "-c", RECORD_DELETIONS + textwrap.dedent(body)], env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_the_recorder_sees_a_key_another_thread_deletes_from_the_environment() -> None:
    """What broke the launch, made on purpose: the recorder must see it, or the test below proves nothing."""
    out = run_fresh(
        """
        os.environ["ARMNET_PROBE_MAIN_FREE"] = "1"
        thread = threading.Thread(target=lambda: os.environ.pop("ARMNET_PROBE_MAIN_FREE"))
        thread.start(); thread.join()
        print(",".join(Recording.deleted))
        """
    )
    assert out.split(",") == ["ARMNET_PROBE_MAIN_FREE"]


def test_the_locked_numpy_import_in_a_thread_deletes_no_key_from_the_environment() -> None:
    """numpy >= 2.4 edits the environment with putenv only; an older numpy would fail this."""
    out = run_fresh(
        """
        thread = threading.Thread(target=lambda: __import__("numpy"))
        thread.start(); thread.join()
        print(",".join(Recording.deleted) or "-")
        """
    )
    assert out == "-"


def test_after_it_the_warm_imports_thread_deletes_nothing_while_the_main_thread_walks_the_environment() -> None:
    out = run_fresh(
        """
        from armnet_connector.warm_imports import DEVICE_MODULES, import_before_threads, start_warm_imports

        import_before_threads()
        Recording.deleted.clear()
        warm = start_warm_imports(DEVICE_MODULES)
        walks = 0
        while warm.is_alive():
            dict(os.environ.items())  # what requests' proxy lookup does; raised KeyError before
            walks += 1
            time.sleep(0.001)
        import sys
        loaded = all(name in sys.modules for name in DEVICE_MODULES)
        print(loaded, walks, ",".join(Recording.deleted) or "-")
        """
    )
    loaded, walks, deleted = out.split()
    assert loaded == "True" and deleted == "-"
    assert int(walks) > 0
