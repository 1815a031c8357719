"""``SimulatedCamera``: LeRobot's Camera interface, drawing the simulated arm."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest
from armnet_sim import RemoteArm, SimulatedCamera, build_cell
from lerobot.cameras import ColorMode, Cv2Rotation
from lerobot.cameras.opencv import OpenCVCameraConfig
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from .sim_lerobot_helpers import Steady, a_feetech_bus, wait_until

pytestmark = pytest.mark.unit


def a_config(**overrides: object) -> OpenCVCameraConfig:
    # warmup_s=0: these tests are not about connect()'s timing (see the warm-up test).
    fields: dict[str, object] = {"index_or_path": 0, "fps": 30, "width": 320, "height": 240, "warmup_s": 0}
    fields.update(overrides)
    return OpenCVCameraConfig(**fields)  # type: ignore[arg-type]


@pytest.fixture
def camera(so101_arm: RemoteArm) -> Iterator[SimulatedCamera]:
    cam = SimulatedCamera(a_config(), source=so101_arm)
    cam.connect()
    yield cam
    if cam.is_connected:
        cam.disconnect()


def test_read_returns_an_rgb_frame_of_the_requested_size(camera: SimulatedCamera) -> None:
    frame = camera.read()
    assert frame.shape == (240, 320, 3)
    assert frame.dtype == np.uint8
    assert frame.flags["C_CONTIGUOUS"]


def test_async_read_and_read_latest_return_frames(camera: SimulatedCamera) -> None:
    assert camera.async_read(timeout_ms=1000).shape == (240, 320, 3)
    assert camera.read_latest().shape == (240, 320, 3)


def test_a_still_arm_gives_identical_frames(camera: SimulatedCamera) -> None:
    assert np.array_equal(camera.read(), camera.read())


def test_frames_change_when_the_arm_moves_through_lerobot(
    camera: SimulatedCamera, so101_arm: RemoteArm
) -> None:
    before = camera.read()
    bus = Steady(a_feetech_bus(so101_arm))
    bus.connect()
    try:
        bus.enable_torque()
        bus.sync_write("Goal_Position", {"shoulder_lift": -40.0, "elbow_flex": 35.0})
        assert wait_until(lambda: abs(bus.read("Present_Position", "elbow_flex") - 35.0) < 0.2)
    finally:
        bus.disconnect()
    after = camera.read()
    assert not np.array_equal(before, after)


def test_bgr_mode_swaps_the_channels(so101_arm: RemoteArm) -> None:
    frames = {}
    for mode in (ColorMode.RGB, ColorMode.BGR):
        with SimulatedCamera(a_config(color_mode=mode), source=so101_arm) as cam:
            frames[mode] = cam.read()
    assert np.array_equal(frames[ColorMode.RGB], frames[ColorMode.BGR][:, :, ::-1])
    assert not np.array_equal(frames[ColorMode.RGB], frames[ColorMode.BGR])


def test_a_quarter_turn_rotation_keeps_the_configured_shape(so101_arm: RemoteArm) -> None:
    with SimulatedCamera(a_config(rotation=Cv2Rotation.ROTATE_90), source=so101_arm) as cam:
        assert cam.read().shape == (240, 320, 3)


def test_unset_size_and_fps_take_webcam_defaults() -> None:
    cam = SimulatedCamera(OpenCVCameraConfig(index_or_path=0, warmup_s=0))
    assert (cam.width, cam.height, cam.fps) == (640, 480, 30)
    with cam:
        assert cam.read().shape == (480, 640, 3)


def test_a_bimanual_cell_renders_both_arms_and_each_one_matters() -> None:
    with build_cell("bimanual_so101") as cell:
        with SimulatedCamera(a_config(), source=cell) as cam:
            before = cam.read()
            cell.arms["right"].move_by_hand("shoulder_lift", 2900)
            assert wait_until(lambda: not np.array_equal(before, cam.read_latest()))


def test_a_callable_source_is_accepted_and_attach_switches_it() -> None:
    angles = {"shoulder_lift": 0.0, "elbow_flex": 0.0}
    with SimulatedCamera(a_config(), source=lambda: angles) as cam:
        first = cam.read()
        cam.attach(lambda: {"shoulder_lift": 30.0, "elbow_flex": -20.0})
        assert wait_until(lambda: not np.array_equal(first, cam.read_latest()))


def test_connect_twice_and_reads_when_disconnected_raise_lerobot_errors(
    camera: SimulatedCamera,
) -> None:
    with pytest.raises(DeviceAlreadyConnectedError):
        camera.connect()
    camera.disconnect()
    assert not camera.is_connected
    with pytest.raises(DeviceNotConnectedError):
        camera.read()
    with pytest.raises(DeviceNotConnectedError):
        camera.disconnect()


def test_frames_returned_to_callers_are_private_copies(camera: SimulatedCamera) -> None:
    frame = camera.read_latest()
    frame[:] = 255
    assert not np.array_equal(camera.read_latest(), frame)


def test_connect_takes_the_configured_warm_up_as_a_real_camera_does() -> None:
    cam = SimulatedCamera(a_config(warmup_s=1))
    started = time.monotonic()
    cam.connect()
    try:
        assert time.monotonic() - started >= 1.0  # OpenCVCamera streams for warmup_s before returning
    finally:
        cam.disconnect()


def test_read_accepts_the_deprecated_color_mode_and_keeps_the_configured_order(camera: SimulatedCamera) -> None:
    frame = camera.read(ColorMode.BGR)  # LeRobot 0.4.4 warns and ignores it
    assert frame.shape == (240, 320, 3)


def test_rotation_backend_and_capture_size_read_as_on_opencv_camera() -> None:
    import cv2

    cam = SimulatedCamera(a_config(rotation=Cv2Rotation.ROTATE_90))
    assert cam.rotation == cv2.ROTATE_90_CLOCKWISE
    assert (cam.capture_width, cam.capture_height) == (240, 320)
    assert cam.backend == a_config().backend
    assert SimulatedCamera(a_config()).rotation is None


def test_each_rendered_picture_is_its_own_and_drawing_on_one_leaves_the_next_clean() -> None:
    """render_arms copies one cached background per size: a picture a caller draws on (or one
    arm drawn in place) must never reach the next picture."""
    from armnet_sim.render import render_arms

    joints = {"shoulder_lift": 10.0, "elbow_flex": 20.0, "wrist_flex": 5.0, "gripper": 30.0}
    for arms in ({"arm": joints}, {"left": joints, "right": joints}, {}):
        first = render_arms(arms, 320, 240)
        assert first.flags.writeable and first.flags.c_contiguous
        first[:] = 255
        again = render_arms(arms, 320, 240)
        assert not np.array_equal(first, again)
        assert np.array_equal(again, render_arms(arms, 320, 240))
    moved = render_arms({"arm": {**joints, "elbow_flex": 60.0}}, 320, 240)
    assert not np.array_equal(moved, render_arms({"arm": joints}, 320, 240))
    assert np.array_equal(render_arms({"arm": joints}, 320, 240)[0, 0], (32, 34, 40))  # the background
