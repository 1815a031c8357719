"""LeRobot's ``OpenCVCamera`` API through the proxy behaves as a camera in the same process.

Every rule runs twice: on a ``SimulatedCamera`` built directly (the reference:
the simulator's stand-in for ``OpenCVCamera``, same errors) and on a
``RemoteOpenCVCamera`` served by a real connector whose frames go through the
shared-memory frame area. Both draw the same fixed pose, so their frames are equal.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from armnet_connector import Connector
from armnet_sim.camera import SimulatedCamera
from lerobot.cameras.opencv import OpenCVCameraConfig
from lerobot.utils.errors import DeviceNotConnectedError

from .conftest import fixed_pose

pytestmark = pytest.mark.unit

SLOW_FPS = 2
"""Frames 500 ms apart: a short wait right after a frame surely sees no newer one."""


def a_config(fps: int = 30) -> OpenCVCameraConfig:
    return OpenCVCameraConfig(index_or_path="front", fps=fps, width=640, height=480)


@pytest.fixture(params=["direct", "proxy"])
def open_camera(
    request: pytest.FixtureRequest, make_connector: Callable[..., Connector], monkeypatch: pytest.MonkeyPatch
) -> Iterator[Callable[..., Any]]:
    cameras: list[Any] = []

    def make(fps: int = 30) -> Any:
        if request.param == "direct":
            camera: Any = SimulatedCamera(a_config(fps), source=fixed_pose)
        else:
            from armnet_runtime.lerobot import RemoteOpenCVCamera

            connector = make_connector(fps=fps).start()
            monkeypatch.setenv("ARMNET_CELL_SOCKET", connector.robot_endpoint)
            camera = RemoteOpenCVCamera(a_config(fps))
        cameras.append(camera)
        camera.connect()
        return camera

    yield make
    for camera in cameras:
        if camera.is_connected:
            camera.disconnect()


@pytest.fixture
def reference_frame() -> np.ndarray:
    camera = SimulatedCamera(a_config(), source=fixed_pose)
    camera.connect()
    try:
        return camera.read()
    finally:
        camera.disconnect()


def test_read_returns_the_simulators_frame_as_an_array_the_caller_owns(
    open_camera: Callable[..., Any], reference_frame: np.ndarray
) -> None:
    frame = open_camera().read()
    assert frame.dtype == np.uint8 and frame.shape == (480, 640, 3)
    assert np.array_equal(frame, reference_frame)
    frame[0, 0] = 255 - frame[0, 0]  # writable, and drawing on it changes no later frame


def test_read_latest_returns_the_newest_frame_without_waiting(
    open_camera: Callable[..., Any], reference_frame: np.ndarray
) -> None:
    camera = open_camera()
    first, second = camera.read_latest(), camera.read_latest(max_age_ms=1000)
    assert np.array_equal(first, reference_frame) and np.array_equal(second, reference_frame)
    assert first is not second


def test_read_latest_of_a_frame_older_than_max_age_raises_timeout_error(open_camera: Callable[..., Any]) -> None:
    camera = open_camera(fps=SLOW_FPS)
    camera.async_read(timeout_ms=2000)
    with pytest.raises(TimeoutError, match="too old"):
        camera.read_latest(max_age_ms=0)


def test_async_read_waits_for_a_frame_newer_than_the_last_one_returned(open_camera: Callable[..., Any]) -> None:
    camera = open_camera(fps=1)
    camera.async_read(timeout_ms=3000)  # consumes the newest frame, which may be any age
    camera.async_read(timeout_ms=3000)  # waits for a new one: the next is a whole period away
    with pytest.raises(TimeoutError, match="Timed out waiting for frame"):
        camera.async_read(timeout_ms=50)
    assert camera.async_read(timeout_ms=2000).shape == (480, 640, 3)


def test_every_read_after_disconnect_raises_device_not_connected(open_camera: Callable[..., Any]) -> None:
    camera = open_camera()
    camera.read_latest()
    camera.disconnect()
    for read in (camera.read, camera.async_read, camera.read_latest):
        with pytest.raises(DeviceNotConnectedError):
            read()


def test_a_reconnected_camera_serves_frames_again(
    open_camera: Callable[..., Any], reference_frame: np.ndarray
) -> None:
    camera = open_camera()
    camera.read_latest()
    camera.disconnect()
    camera.connect()
    assert np.array_equal(camera.read_latest(), reference_frame)
    assert np.array_equal(camera.async_read(timeout_ms=2000), reference_frame)

