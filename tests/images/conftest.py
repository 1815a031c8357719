"""The shipped images, built once per content hash (armnet_testbed.shipped_images).

A warm session finds every tag in Podman and builds nothing; a cold one builds the
dependency locks (PyPI) and images (the agent's, with torch, takes minutes).
"""

from __future__ import annotations

from typing import Any

import pytest
from armnet_testbed.plugin import Podman, _start
from armnet_testbed.shipped_images import (
    AGENT,
    OPERATOR,
    RUNTIME,
    RUNTIME_LEROBOT,
    ImageSpec,
    ensure_image,
)


def _image(spec: ImageSpec, podman: Podman, request: pytest.FixtureRequest) -> str:
    return str(_start(f"the {spec.name} image", lambda: ensure_image(spec, client=podman.client),
                      request))


@pytest.fixture(scope="session")
def runtime_image(podman: Podman, base_image: str, request: pytest.FixtureRequest) -> str:
    return _image(RUNTIME, podman, request)


@pytest.fixture(scope="session")
def runtime_lerobot_image(podman: Podman, agent_image: str, request: pytest.FixtureRequest) -> str:
    """Built after the agent image: both share the `lerobot` lock's venv layer."""
    return _image(RUNTIME_LEROBOT, podman, request)


@pytest.fixture(scope="session")
def operator_image(podman: Podman, base_image: str, request: pytest.FixtureRequest) -> str:
    return _image(OPERATOR, podman, request)


@pytest.fixture(scope="session")
def agent_image(podman: Podman, base_image: str, request: pytest.FixtureRequest) -> str:
    return _image(AGENT, podman, request)


def run_image(podman: Podman, image: str, command: list[str] | None = None, *,
              entrypoint: list[str] | None = None, environment: dict[str, str] | None = None,
              **kwargs: Any) -> tuple[int, str]:
    """Run ``image`` to its end without network; (exit code, stdout + stderr).

    No window of its own: these commands import LeRobot and torch, whose time under the
    suite's load has no useful bound (docs/testing.md, "A loaded host": a single ``import
    torch`` past 300 s at load 7), and they check what an image holds, not how fast it
    starts. The test's own timeout (pytest's ``--timeout``) is the one bound; the client's
    read timeout (300 s) outlasts it.
    """
    container = podman.client.containers.run(
        image, command, entrypoint=entrypoint, environment=environment or {}, detach=True,
        network_mode="none", ulimits=podman.ulimits(), **kwargs)
    try:
        code = int(container.wait()["StatusCode"])
        return code, container.logs(stdout=True, stderr=True).decode(errors="replace")
    finally:
        container.remove(force=True)
