"""The test bed: real etcd + kube-apiserver, a real node, NATS (JetStream) and Podman's API.

Everything here starts real processes on free loopback ports, in temporary
directories, and stops and removes them again. Used by the pytest plugin
(``armnet_testbed.plugin``) and by ``armnet dev up``. Nothing here is mocked; a
missing binary raises :class:`TestbedSetupError` naming ``scripts/setup.sh``.
"""

from armnet_testbed.controllers import WorkloadControllers
from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.images import BASE_IMAGE, build_wheels, require_base_image
from armnet_testbed.kube import ControlPlane, KubeUser
from armnet_testbed.natsd import NatsServer
from armnet_testbed.node import Node
from armnet_testbed.objstore import SeaweedS3
from armnet_testbed.podman import PodmanService

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
