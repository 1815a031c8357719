"""Camera frames as the page gets them: JPEG, scaled to the published width, colours in the right order."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from armnet_connector.telemetry import CameraFrame
from armnet_node.telemetry import encode_jpeg

pytestmark = pytest.mark.unit


def decoded(jpeg: bytes) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)  # BGR
    assert image is not None
    return image


def test_a_frame_is_scaled_to_the_published_width() -> None:
    jpeg = encode_jpeg(CameraFrame(np.zeros((480, 640, 3), np.uint8)))
    assert decoded(jpeg).shape == (240, 320, 3)


def test_an_rgb_frame_keeps_its_colours() -> None:
    red = np.zeros((48, 64, 3), np.uint8)
    red[..., 0] = 255  # red in RGB
    blue, green, r = decoded(encode_jpeg(CameraFrame(red))).reshape(-1, 3).mean(axis=0)
    assert r > 200 and blue < 50 and green < 50


def test_a_bgr_frame_keeps_its_colours() -> None:
    red = np.zeros((48, 64, 3), np.uint8)
    red[..., 2] = 255  # red in BGR
    blue, green, r = decoded(encode_jpeg(CameraFrame(red, bgr=True))).reshape(-1, 3).mean(axis=0)
    assert r > 200 and blue < 50 and green < 50


@pytest.mark.parametrize("image", [np.zeros((48, 64), np.uint8), np.zeros((48, 64, 3), np.float32),
                                   np.zeros((48, 64, 4), np.uint8)])
def test_what_is_not_an_hxwx3_byte_picture_is_refused(image: np.ndarray) -> None:
    with pytest.raises(ValueError, match="HxWx3 uint8"):
        encode_jpeg(CameraFrame(image))
