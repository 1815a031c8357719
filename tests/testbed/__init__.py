"""The test bed: real etcd + kube-apiserver, a real node, NATS (JetStream) and Podman's API.

Everything here starts real processes on free loopback ports, in temporary
directories, and stops and removes them again. Used by the pytest plugin
(``tests.testbed.plugin``) and by ``armnet dev up``. Nothing here is mocked; a
missing binary raises :class:`TestbedSetupError` naming ``scripts/setup.sh``.
"""

from tests.testbed.controllers import WorkloadControllers
from tests.testbed.errors import TestbedSetupError
from tests.testbed.images import BASE_IMAGE, build_wheels, require_base_image
from tests.testbed.kube import ControlPlane, KubeUser
from tests.testbed.natsd import NatsServer
from tests.testbed.node import Node
from tests.testbed.objstore import SeaweedS3
from tests.testbed.podman import PodmanService

__all__ = [
    "BASE_IMAGE",
    "ControlPlane",
    "KubeUser",
    "NatsServer",
    "Node",
    "PodmanService",
    "SeaweedS3",
    "TestbedSetupError",
    "WorkloadControllers",
    "build_wheels",
    "require_base_image",
]
