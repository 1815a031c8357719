"""The image builder removes the build directories a failed build left in /var/tmp, and only those."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from armnet_testbed.shipped_images import STALE_BUILD_DIR_S, _drop_stale_build_dirs

pytestmark = pytest.mark.unit


def test_only_podmans_old_build_directories_are_removed(tmp_path: Path) -> None:
    now = 1_000_000.0
    old, fresh = now - STALE_BUILD_DIR_S - 60, now - 60
    made = {}
    for name, when in (("libpod_builder172382679", old), ("buildah3840563839", old), ("storage3036310", old),
                       ("libpod_builder1005511795", fresh), ("storage-of-someone", old), ("systemd-private", old)):
        path = tmp_path / name
        (path / "context").mkdir(parents=True)
        (path / "context" / "wheel.whl").write_bytes(b"x" * 10)
        os.utime(path, (when, when))
        made[name] = path

    removed = _drop_stale_build_dirs(tmp_path, now)

    assert {p.name for p in removed} == {"libpod_builder172382679", "buildah3840563839", "storage3036310"}
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "libpod_builder1005511795", "storage-of-someone", "systemd-private"]
