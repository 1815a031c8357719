"""The frame descriptor on the wire: what the connector sends, what either side refuses, the inline fallback."""

from __future__ import annotations

import json
import logging
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from armnet_connector import Connector
from armnet_connector.frames import FrameAreas, FramePublisher
from armnet_runtime.errors import ProtocolError
from armnet_runtime.frames import FrameReader
from armnet_runtime.transport import PersistentConnection
from armnet_runtime.wire import decode, encode
from armnet_sim.camera import SimulatedCamera
from lerobot.cameras.opencv import OpenCVCameraConfig

from .conftest import fixed_pose

pytestmark = pytest.mark.unit


def a_config() -> OpenCVCameraConfig:
    return OpenCVCameraConfig(index_or_path="front", fps=30, width=640, height=480)


@pytest.fixture
def connection(make_connector: Callable[..., Connector]) -> Iterator[tuple[PersistentConnection, str]]:
    connector = make_connector().start()
    conn = PersistentConnection(connector.robot_endpoint, timeout=10)
    reply = conn.request({"op": "create", "class": "OpenCVCamera", "args": [encode(a_config())], "kwargs": {}})
    object_id = reply["object_id"]
    assert conn.request({"op": "call", "object_id": object_id, "method": "connect", "args": [], "kwargs": {}})["ok"]
    yield conn, object_id
    conn.close()


def a_read(object_id: str, **fields: Any) -> dict[str, Any]:
    return {"op": "call", "object_id": object_id, "method": "read", "args": [], "kwargs": {}, **fields}


def test_a_camera_read_asking_for_shared_memory_is_answered_with_a_descriptor_not_pixels(
    connection: tuple[PersistentConnection, str], socket_dir: Path
) -> None:
    conn, object_id = connection
    reply = conn.request(a_read(object_id, frames="shm"))
    assert "value" not in reply and len(json.dumps(reply)) < 512
    assert set(reply["frame"]) == {"area", "camera", "slot", "sequence", "shape", "dtype", "timestamp"}
    assert reply["frame"]["camera"] == "front" and reply["frame"]["shape"] == [480, 640, 3]
    assert (socket_dir / reply["frame"]["area"]).is_file()


def test_a_garbage_frames_field_is_refused_and_the_connection_keeps_serving(
    connection: tuple[PersistentConnection, str],
) -> None:
    conn, object_id = connection
    reply = conn.request(a_read(object_id, frames={"slot": -1}))
    assert reply["ok"] is False and reply["error_type"] == "ProtocolError"
    assert "'frames' must be 'shm' or 'inline'" in reply["error"]
    assert conn.request(a_read(object_id, frames="shm"))["ok"] is True


@pytest.mark.parametrize(
    ("descriptor", "names"),
    [
        ({"area": "../../etc/shadow", "camera": "x", "slot": 0, "sequence": 1, "shape": [1], "dtype": "uint8", "timestamp": 0.0}, "frame area"),
        ({"area": "frames-a.shm", "camera": "x", "slot": 99, "sequence": 1, "shape": [1], "dtype": "uint8", "timestamp": 0.0}, "'slot'"),
        ({"area": "frames-a.shm", "camera": "x", "slot": 0, "sequence": 1, "shape": "480x640", "dtype": "uint8", "timestamp": 0.0}, "'shape'"),
        ({"area": "frames-a.shm", "camera": "x", "slot": 0, "sequence": 0, "shape": [1], "dtype": "uint8", "timestamp": 0.0}, "'sequence'"),
        ({"area": "frames-a.shm", "camera": "x"}, "lacks the field"),
        (["not", "an", "object"], "must be an object"),
    ],
)
def test_a_garbage_descriptor_is_refused_with_a_protocol_error_naming_the_field(
    descriptor: Any, names: str, socket_dir: Path
) -> None:
    with pytest.raises(ProtocolError, match=names):
        FrameReader(socket_dir).copy(descriptor)


def test_a_descriptor_whose_frame_does_not_fit_its_area_is_refused(socket_dir: Path) -> None:
    published = FramePublisher(socket_dir, "front").publish(np.zeros((4, 4), np.uint8))
    assert published is not None
    oversized = {**published, "shape": [4096, 4096]}
    with pytest.raises(ProtocolError, match="does not fit"):
        FrameReader(socket_dir).copy(oversized)


@pytest.mark.parametrize(
    "frame",
    [
        np.arange(480 * 640, dtype=np.uint16).reshape(480, 640),  # depth in millimetres
        np.linspace(0, 5, 480 * 640, dtype=np.float32).reshape(480, 640, 1),
        np.random.default_rng(7).integers(0, 255, (480, 640, 3), dtype=np.uint8)[:, ::-1],  # not contiguous
        np.arange(12, dtype=">i4").reshape(3, 4),  # big-endian
    ],
    ids=["depth-uint16", "float32", "bgr-view", "big-endian"],
)
def test_every_numeric_frame_crosses_the_area_with_its_values_and_shape(frame: np.ndarray, socket_dir: Path) -> None:
    descriptor = FramePublisher(socket_dir, "depth").publish(frame)
    copied = FrameReader(socket_dir).copy(descriptor)
    assert copied.shape == frame.shape and np.array_equal(copied, frame)
    assert copied.dtype == frame.dtype.newbyteorder("=")


def test_the_inline_encoding_round_trips_a_480x640x3_frame_exactly() -> None:
    frame = np.random.default_rng(3).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    back = decode(json.loads(json.dumps(encode(frame))))
    assert back.dtype == np.uint8 and back.shape == (480, 640, 3) and np.array_equal(back, frame)


def test_a_proxy_that_cannot_map_the_area_says_so_once_and_gets_exact_frames_inline(
    make_connector: Callable[..., Connector], monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from armnet_runtime.lerobot import RemoteOpenCVCamera

    connector = make_connector()
    with tempfile.TemporaryDirectory(prefix="adp-elsewhere-", dir="/dev/shm") as elsewhere:
        connector.frames = FrameAreas(Path(elsewhere))  # a directory this "container" does not see
        connector.start()
        monkeypatch.setenv("ARMNET_CELL_SOCKET", connector.robot_endpoint)
        direct = SimulatedCamera(a_config(), source=fixed_pose)
        direct.connect()
        camera = RemoteOpenCVCamera(a_config())
        camera.connect()
        with caplog.at_level(logging.WARNING, logger="armnet_runtime.lerobot"):
            frames = [camera.read(), camera.async_read(timeout_ms=2000), camera.read_latest()]
        camera.disconnect()
        expected = direct.read()
        direct.disconnect()
    assert all(np.array_equal(frame, expected) for frame in frames)
    fallbacks = [r for r in caplog.records if "travel inline" in r.getMessage()]
    assert len(fallbacks) == 1


def test_a_frame_that_outgrows_its_area_moves_to_a_new_one_and_the_reader_follows(socket_dir: Path) -> None:
    publisher, reader = FramePublisher(socket_dir, "front"), FrameReader(socket_dir)
    small = publisher.publish(np.full((240, 320, 3), 1, np.uint8))
    large = publisher.publish(np.full((480, 640, 3), 2, np.uint8))
    assert small is not None and large is not None and small["area"] != large["area"]
    assert not (socket_dir / small["area"]).exists()
    assert np.array_equal(reader.copy(large), np.full((480, 640, 3), 2, np.uint8))


def test_the_area_goes_away_with_the_connection_that_made_it(
    connection: tuple[PersistentConnection, str], socket_dir: Path
) -> None:
    conn, object_id = connection
    area = socket_dir / conn.request(a_read(object_id, frames="shm"))["frame"]["area"]
    conn.close()
    deadline = time.monotonic() + 10
    while area.exists() and time.monotonic() < deadline:
        time.sleep(0.01)  # the connector notices the closed connection on its own thread
    assert not area.exists()



def test_the_connector_counts_frames_published_and_areas_created(make_connector: Callable[..., Connector]) -> None:
    connector = make_connector().start()
    with PersistentConnection(connector.robot_endpoint, timeout=10) as conn:
        object_id = conn.request({"op": "create", "class": "OpenCVCamera", "args": [encode(a_config())], "kwargs": {}})[
            "object_id"
        ]
        conn.request({"op": "call", "object_id": object_id, "method": "connect", "args": [], "kwargs": {}})
        conn.request(a_read(object_id, frames="shm"))
    counters = connector.frames.counters
    assert counters.areas == 1 and counters.published >= 2 and counters.inline_cameras == 0
