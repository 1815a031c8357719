"""Which of the node's images an install's images supersede: only earlier common tags of its own repositories."""

from __future__ import annotations

import pytest
from armnet_testbed.release_images import ReleaseImages

pytestmark = pytest.mark.unit

IMAGES = ReleaseImages(operator="localhost/armnet-operator:it-aaaaaabbbbbb",
                       agent="localhost/armnet-agent:it-aaaaaabbbbbb", tag="it-aaaaaabbbbbb",
                       example_job="localhost/armnet-example-job:it", bus_loop="localhost/armnet-bus-loop:it",
                       unattended_eval="localhost/armnet-unattended-eval:it")


@pytest.mark.parametrize("name", ["localhost/armnet-operator:it-111111222222",
                                  "localhost/armnet-agent:it-0"])
def test_an_earlier_common_tag_of_the_operator_or_agent_is_superseded(name: str) -> None:
    assert IMAGES.is_superseded(name)


@pytest.mark.parametrize("name", [
    "localhost/armnet-operator:it-aaaaaabbbbbb",  # this install's own
    "localhost/armnet-agent:dev",  # not a common tag
    "localhost/armnet-agent:0123456789ab",  # a content-hash build
    "localhost/armnet-example-job:it",  # the customer images keep their one name
    "localhost/armnet-pause:testbed",
    "localhost/other:it-111111222222",  # another repository's
])
def test_this_install_s_images_and_other_names_are_kept(name: str) -> None:
    assert not IMAGES.is_superseded(name)
