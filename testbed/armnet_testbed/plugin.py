"""pytest plugin: session-scoped real services for the integration, container and e2e tiers.

Fixtures (all start lazily, only when a test asks for them, and stop at session end):

- ``k8s`` -> :class:`K8s`: etcd + kube-apiserver (TLS, RBAC, SA issuer, CRDs applied).
- ``namespace`` -> ``str``: a fresh namespace per test, deleted afterwards.
- ``nats_server`` -> ``str``: the ``nats://`` URL of a JetStream-enabled nats-server.
- ``nats_service`` -> :class:`NatsServer` (``.url``, ``.restart()``); not named ``nats``
  so it never shadows the ``nats`` package in a test.
- ``object_store`` -> :class:`SeaweedS3`: SeaweedFS's S3 gateway (``.endpoint``,
  ``.access_key``, ``.secret_key``, ``.client()``).
- ``podman`` -> :class:`Podman`: the Docker client on Podman's API socket.
- ``base_image`` -> ``str``: the base image reference (``localhost/armnet-base:bookworm``).
- ``k8s_node`` -> :class:`Node`: containerd + a kubelet registered with ``k8s`` as a
  ``Ready`` Node (pause and base images imported; ``.import_image()`` for more).

A missing binary, tool or image FAILS the test (``TestbedSetupError``) with a hint to
run ``scripts/setup.sh``; nothing is skipped.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from armnet_testbed.errors import TestbedSetupError
from armnet_testbed.images import BASE_IMAGE, require_base_image
from armnet_testbed.kube import ControlPlane, KubeUser
from armnet_testbed.natsd import NatsServer
from armnet_testbed.node import Node
from armnet_testbed.objstore import SeaweedS3
from armnet_testbed.podman import PodmanService, ulimits

K8s = ControlPlane  # the `k8s` fixture's type: .kubeconfig .url .admin_token .user() .kubectl()


@dataclass(frozen=True)
class Podman:
    """What the ``podman`` fixture gives: the Docker client, its socket, and helpers."""

    client: Any
    socket_path: Path
    base_url: str

    def ulimits(self) -> list[Any]:
        """Explicit ulimits every container needs on this engine (the API ignores defaults)."""
        return ulimits()


def _start(what: str, start: Any, request: pytest.FixtureRequest) -> Any:
    """Run ``start`` with output capture off, so progress lines reach the terminal."""
    capture = request.config.pluginmanager.getplugin("capturemanager")
    guard = capture.global_and_fixture_disabled() if capture else contextlib.nullcontext()
    try:
        with guard:
            return start()
    except TestbedSetupError as exc:
        problem = str(exc)
    pytest.fail(f"test bed: {what} is not available: {problem}", pytrace=False)


@pytest.fixture(scope="session")
def k8s(request: pytest.FixtureRequest) -> Iterator[ControlPlane]:
    plane = ControlPlane()
    _start("Kubernetes control plane", plane.start, request)
    try:
        yield plane
    finally:
        plane.stop()


@pytest.fixture(scope="session")
def k8s_node(k8s: ControlPlane, request: pytest.FixtureRequest) -> Iterator[Node]:
    node = Node(plane=k8s)
    _start("Kubernetes node (containerd + kubelet)", node.start, request)
    try:
        yield node
    finally:
        node.stop()


@pytest.fixture
def namespace(k8s: ControlPlane, request: pytest.FixtureRequest) -> Iterator[str]:
    name = k8s.create_namespace(request.node.name.removeprefix("test_"))
    try:
        yield name
    finally:
        k8s.delete_namespace(name)


@pytest.fixture(scope="session")
def nats_service(request: pytest.FixtureRequest) -> Iterator[NatsServer]:
    server = NatsServer()
    _start("nats-server", server.start, request)
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture(scope="session")
def nats_server(nats_service: NatsServer) -> str:
    return nats_service.url


#: Tenants' read-only keys on the session's store, for the tests of what a tenant's keys reach
#: (tests/integration/test_tenant_output_keys.py): the bucket and the namespaces they name. A store's
#: identities are fixed when it starts, and a store of their own cost those tests ~27 s (start and stop).
TENANT_KEYS_BUCKET = "tenant-outputs"
TENANT_KEYS_NAMESPACES = ("tenant-keys-a", "tenant-keys-b")
#: A read-only identity for the whole of one bucket: the FMS's keys (tests/integration/test_fms_last_video.py).
FMS_READER, FMS_VIDEO_BUCKET = "fms-reader", "fms-videos"


@pytest.fixture(scope="session")
def object_store(request: pytest.FixtureRequest) -> Iterator[SeaweedS3]:
    server = SeaweedS3(readers={**{ns: (TENANT_KEYS_BUCKET, ns) for ns in TENANT_KEYS_NAMESPACES},
                                FMS_READER: (FMS_VIDEO_BUCKET, "")})
    _start("SeaweedFS S3 object store", server.start, request)
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture(scope="session")
def podman(request: pytest.FixtureRequest) -> Iterator[Podman]:
    service = PodmanService()
    _start("Podman Docker-compatible API", service.start, request)
    try:
        yield Podman(client=service.client, socket_path=service.socket_path,
                     base_url=service.base_url)
    finally:
        service.stop()


@pytest.fixture(scope="session")
def base_image(podman: Podman, request: pytest.FixtureRequest) -> str:
    _start("container base image", lambda: require_base_image(podman.client), request)
    return BASE_IMAGE


__all__ = ["K8s", "KubeUser", "Node", "Podman", "SeaweedS3"]
