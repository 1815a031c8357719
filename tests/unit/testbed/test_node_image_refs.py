"""The test-bed node's image cleanup: which CRI image-id references hold content no name uses."""

from __future__ import annotations

import pytest
from armnet_testbed.containerd import orphan_image_ids

pytestmark = pytest.mark.unit

LISTING = """\
REF                                     TYPE                                       DIGEST      SIZE     PLATFORMS   LABELS
localhost/armnet-agent:it-new           application/vnd.docker.distribution.manifest.v2+json sha256:aaa 5.6 GiB linux/amd64 -
localhost/armnet-pause:testbed          application/vnd.docker.distribution.manifest.v2+json sha256:ppp 669 KiB linux/amd64 -
sha256:1111                             application/vnd.docker.distribution.manifest.v2+json sha256:aaa 5.6 GiB linux/amd64 io.cri-containerd.image=managed
sha256:2222                             application/vnd.docker.distribution.manifest.v2+json sha256:old 5.6 GiB linux/amd64 io.cri-containerd.image=managed
sha256:3333                             application/vnd.docker.distribution.manifest.v2+json sha256:ppp 669 KiB linux/amd64 io.cri-containerd.image=managed
"""


def test_an_id_reference_of_an_untagged_image_is_an_orphan_and_named_ones_are_kept() -> None:
    assert orphan_image_ids(LISTING) == ["sha256:2222"]


def test_an_empty_listing_has_no_orphans() -> None:
    assert orphan_image_ids("REF TYPE DIGEST SIZE PLATFORMS LABELS\n") == []
