"""Setup's import into the test-bed node's image store (scripts/setup.d/55-node-images.sh): a
containerd of its own, no kubelet, under the node lock; what it imports a node finds there.

Runs before its session's node fixture takes the host's node lock (scripts/test.sh), like
test_dev_up.py: ``import_into_store`` waits for that lock.
"""

from __future__ import annotations

import subprocess

import pytest
from armnet_testbed.containerd import (
    SOURCE_LABEL,
    Containerd,
    hold_node_lock,
    import_into_store,
    release_node_lock,
)
from armnet_testbed.images import BASE_IMAGE

pytestmark = [pytest.mark.node, pytest.mark.integration, pytest.mark.timeout(600)]


def podman_id(image: str) -> str:
    return subprocess.run(["podman", "image", "inspect", "--format", "{{.Id}}", image], capture_output=True,
                          text=True, check=True).stdout.strip()


def store_listing(image: str, tmp_path_factory: pytest.TempPathFactory) -> str:
    """``ctr images ls`` of ``image`` in the store, read by a containerd of the test's own."""
    lock = hold_node_lock(600)
    containerd = Containerd(tmp_path_factory.mktemp("containerd"))
    try:
        (containerd.workdir / "cni").mkdir()
        containerd.start(containerd.workdir / "cni")
        return containerd.ctr("images", "ls", f"name=={image}").stdout
    finally:
        containerd.stop()
        release_node_lock(lock)


def test_an_image_setup_imports_is_in_the_store_with_its_podman_id_and_is_not_imported_twice(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    # Forgotten first, so that this run imports it whatever an earlier run left.
    assert import_into_store([BASE_IMAGE], forget=lambda name: name == BASE_IMAGE) == [BASE_IMAGE]
    assert f"{SOURCE_LABEL}={podman_id(BASE_IMAGE)}" in store_listing(BASE_IMAGE, tmp_path_factory)
    assert import_into_store([BASE_IMAGE]) == []


def test_an_image_podman_does_not_have_is_refused_by_name() -> None:
    with pytest.raises(Exception, match="localhost/armnet-no-such-image:x is not in podman"):
        import_into_store(["localhost/armnet-no-such-image:x"])
