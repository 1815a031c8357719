"""``SimulatedCamera``: LeRobot's ``Camera`` interface over the simulated joint state.

On a simulated cell the connector builds this where it would build
``OpenCVCamera(config)``: same constructor (a camera config), same methods
(``connect``, ``read``, ``async_read``, ``read_latest``, ``disconnect``,
``is_connected``) and the same errors, and frames of the requested size, colour
order and rate. ``connect()`` takes the config's ``warmup_s`` as a real
``OpenCVCamera.connect()`` does (it reads frames until the warm-up has passed,
about 1 s by default), so local timing is honest; a cell config that sets
``warmup_s: 0`` skips it. The picture is rendered from a joint-state source attached with
``source=`` or ``attach()``: an object with ``joint_angles()`` (a
``SimulatedArm`` or ``SimulatedCell``) or any callable returning joint angles.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np
from lerobot.cameras.camera import Camera
from lerobot.cameras.configs import CameraConfig, ColorMode, Cv2Rotation
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from .render import Image, render_arms

log = logging.getLogger(__name__)

DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_FPS = 640, 480, 30

#: The forms a joint-state source may take; see ``_resolve_state``.
JointSource = Callable[[], Mapping[str, Any]] | Any

_ROTATIONS = {
    Cv2Rotation.ROTATE_90: cv2.ROTATE_90_CLOCKWISE,
    Cv2Rotation.ROTATE_180: cv2.ROTATE_180,
    Cv2Rotation.ROTATE_270: cv2.ROTATE_90_COUNTERCLOCKWISE,
}


class SimulatedCamera(Camera):  # type: ignore[misc]  # lerobot ships no type stubs
    """A camera whose frames draw the simulated arm; a drop-in for ``OpenCVCamera``."""

    def __init__(self, config: CameraConfig, source: JointSource | None = None) -> None:
        super().__init__(config)
        self.config = config
        self.index_or_path = getattr(config, "index_or_path", "sim")
        # Unset fields take a webcam's usual defaults, as OpenCV adopts the device's.
        self.fps = config.fps or DEFAULT_FPS
        self.width = config.width or DEFAULT_WIDTH
        self.height = config.height or DEFAULT_HEIGHT
        self.color_mode = ColorMode(getattr(config, "color_mode", ColorMode.RGB))
        self._rotation = Cv2Rotation(getattr(config, "rotation", Cv2Rotation.NO_ROTATION))
        # What OpenCVCamera exposes: the cv2 rotate code (None: no rotation), the
        # capture backend, and the size frames are captured at (before rotation).
        self.rotation: int | None = _ROTATIONS.get(self._rotation)
        self.backend = getattr(config, "backend", 0)
        quarter = self._rotation in (Cv2Rotation.ROTATE_90, Cv2Rotation.ROTATE_270)
        self.capture_width, self.capture_height = (
            (self.height, self.width) if quarter else (self.width, self.height)
        )
        self.warmup_s = getattr(config, "warmup_s", 1)
        self._source = source
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.frame_lock = threading.Lock()
        self.latest_frame: Image | None = None
        self.latest_timestamp: float | None = None
        self.new_frame_event = threading.Event()
        self.frames_rendered = 0

    def __str__(self) -> str:
        return f"{self.__class__.__name__}({self.index_or_path})"

    def attach(self, source: JointSource | None) -> None:
        """Point the camera at a joint-state source (may change while connected)."""
        self._source = source

    @property
    def is_connected(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @staticmethod
    def find_cameras() -> list[dict[str, Any]]:
        return [{"name": "armnet simulated camera", "type": "armnet-sim", "id": "sim"}]

    def connect(self, warmup: bool = True) -> None:
        """Start the frame thread; like OpenCV, return once a first frame exists."""
        if self.is_connected:
            raise DeviceAlreadyConnectedError(f"{self} is already connected.")
        self._stop.clear()
        self._thread = threading.Thread(target=self._produce, name=f"{self}-frames", daemon=True)
        self._thread.start()
        if warmup:
            # A real camera streams for warmup_s while exposure settles; so does this one.
            settled = time.monotonic() + float(self.warmup_s)
            self.async_read(timeout_ms=max(1000, self.warmup_s * 1000))
            remaining = settled - time.monotonic()
            if remaining > 0:
                self._stop.wait(remaining)

    def read(self, color_mode: ColorMode | None = None) -> Image:
        """Block until the next frame, as ``OpenCVCamera.read`` does.

        ``color_mode`` is accepted and ignored with LeRobot 0.4.4's deprecation
        warning: frames come in the configured colour order.
        """
        if color_mode is not None:
            log.warning("%s read() color_mode parameter is deprecated and will be removed in future versions.", self)
        self._require_running()
        self.new_frame_event.clear()
        return self.async_read(timeout_ms=10000)

    def async_read(self, timeout_ms: float = 200) -> Image:
        self._require_running()
        if not self.new_frame_event.wait(timeout=timeout_ms / 1000.0):
            raise TimeoutError(
                f"Timed out waiting for frame from camera {self} after {timeout_ms} ms."
            )
        with self.frame_lock:
            frame = self.latest_frame
            self.new_frame_event.clear()
        if frame is None:
            raise RuntimeError(f"Internal error: Event set but no frame available for {self}.")
        return frame.copy()  # callers may draw on it; the cached frame must stay clean

    def read_latest(self, max_age_ms: int = 500) -> Image:
        self._require_running()
        with self.frame_lock:
            frame, stamp = self.latest_frame, self.latest_timestamp
        if frame is None or stamp is None:
            raise RuntimeError(f"{self} has not captured any frames yet.")
        age_ms = (time.perf_counter() - stamp) * 1e3
        if age_ms > max_age_ms:
            raise TimeoutError(
                f"{self} latest frame is too old: {age_ms:.1f} ms (max allowed: {max_age_ms} ms)."
            )
        return frame.copy()

    def disconnect(self) -> None:
        if self._thread is None:
            raise DeviceNotConnectedError(f"{self} not connected.")
        self._stop.set()
        self._thread.join(timeout=2)
        self._thread = None
        with self.frame_lock:
            self.latest_frame = None
            self.latest_timestamp = None
            self.new_frame_event.clear()

    # -- frame production --------------------------------------------------------------------

    def _require_running(self) -> None:
        if self._thread is None:
            raise DeviceNotConnectedError(f"{self} is not connected.")
        if not self._thread.is_alive():
            raise RuntimeError(f"{self} read thread is not running.")

    def _produce(self) -> None:
        period = 1.0 / float(self.fps)
        next_tick = time.perf_counter()
        last_state: dict[str, dict[str, float]] = {}
        frame: Image | None = None
        while not self._stop.is_set():
            state = self._resolve_state()
            if state is None:  # the source failed: keep showing the last picture
                state = last_state if frame is not None else {}
            if frame is None or state != last_state:
                frame = self._render(state)
                last_state = state
                self.frames_rendered += 1
            with self.frame_lock:
                self.latest_frame = frame
                self.latest_timestamp = time.perf_counter()
            self.new_frame_event.set()
            next_tick += period
            delay = next_tick - time.perf_counter()
            if delay < 0:  # fell behind (CPU contention): skip, do not burst
                next_tick = time.perf_counter()
                delay = 0
            self._stop.wait(delay)

    def _resolve_state(self) -> dict[str, dict[str, float]] | None:
        """Joint angles per arm, rounded so sub-pixel noise does not force a re-render."""
        source = self._source
        if source is None:
            return {}
        try:
            raw = source.joint_angles() if hasattr(source, "joint_angles") else source()
        except Exception:  # noqa: BLE001 - a failing source must not kill the stream
            log.exception("%s: joint-state source failed; showing the last picture", self)
            return None
        if raw and all(isinstance(v, Mapping) for v in raw.values()):
            arms = raw
        else:
            arms = {"arm": raw}
        return {a: {j: round(float(v), 1) for j, v in joints.items()} for a, joints in arms.items()}

    def _render(self, state: Mapping[str, Mapping[str, float]]) -> Image:
        image = render_arms(state, self.capture_width, self.capture_height)
        if self.rotation is not None:
            image = np.asarray(cv2.rotate(image, self.rotation), dtype=np.uint8)
        if self.color_mode is ColorMode.BGR:
            image = image[:, :, ::-1]
        return np.ascontiguousarray(image)
