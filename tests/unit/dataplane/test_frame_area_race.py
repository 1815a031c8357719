"""A frame area read while another process writes it: every frame returned is whole and exact.

The writer is the connector's own ``FramePublisher`` in a separate process,
publishing the simulator's frames as fast as it can; frame ``k`` is the
simulator's picture of pose ``k % 8`` with ``k`` added to every byte, so a copy
mixing two frames cannot match any frame. A read either returns exactly the
frame of its sequence number or says the frame was overwritten.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from armnet_runtime.frames import FrameOverwritten, FrameReader
from armnet_sim.render import render_arms

pytestmark = pytest.mark.unit

POSES = 8
READS = 100


def pose(index: int) -> dict[str, dict[str, float]]:
    return {"arm": {"shoulder_pan": -40.0 + 10 * index, "elbow_flex": 5.0 * index, "wrist_flex": 20.0}}


def simulator_frames() -> list[np.ndarray]:
    return [render_arms(pose(i), 640, 480) for i in range(POSES)]


def expected_frame(renders: list[np.ndarray], sequence: int) -> np.ndarray:
    return (renders[sequence % POSES] + np.uint8(sequence % 256)).astype(np.uint8)


WRITER = """
import json, sys, time
from pathlib import Path
import numpy as np
from armnet_connector import frames
from armnet_connector.frames import FramePublisher
frames.SLOTS = 2  # fewer slots than the connector uses, so that the writer laps the reader often
sys.path.insert(0, {tests!r})
from test_frame_area_race import expected_frame, simulator_frames

renders = simulator_frames()
publisher = FramePublisher(Path({directory!r}), "front")
publisher.set_connected(True)
k = 0
while True:
    k += 1
    descriptor = publisher.publish(expected_frame(renders, k), time.perf_counter())
    assert descriptor["sequence"] == k
    if k % 10 == 0:
        print(json.dumps(descriptor), flush=True)
"""


@pytest.fixture
def racing_writer(socket_dir: Path) -> Iterator[subprocess.Popen[str]]:
    code = WRITER.format(tests=str(Path(__file__).parent), directory=str(socket_dir))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    yield process
    process.kill()
    process.wait(timeout=10)


def test_a_described_frame_is_the_simulators_frame_of_its_sequence_or_reported_overwritten(
    racing_writer: subprocess.Popen[str], socket_dir: Path
) -> None:
    assert racing_writer.stdout is not None
    renders = simulator_frames()
    reader = FrameReader(socket_dir)
    exact = overwritten = 0
    for _ in range(READS):
        descriptor = json.loads(racing_writer.stdout.readline())
        try:
            frame = reader.copy(descriptor)
        except FrameOverwritten:
            overwritten += 1
            continue
        assert np.array_equal(frame, expected_frame(renders, descriptor["sequence"]))
        exact += 1
    assert exact + overwritten == READS and exact > 0


def test_the_newest_frame_is_never_torn_while_the_writer_races(
    racing_writer: subprocess.Popen[str], socket_dir: Path
) -> None:
    assert racing_writer.stdout is not None
    racing_writer.stdout.readline()  # the area exists and frames are flowing
    renders = simulator_frames()
    background = int(renders[0][0, 0, 0])
    reader = FrameReader(socket_dir)
    while True:  # map the area: the first described frame that is still there
        try:
            reader.copy(json.loads(racing_writer.stdout.readline()))
            break
        except FrameOverwritten:
            continue
    sequences: set[int] = set()
    for _ in range(READS):
        frame = reader.latest(max_age_ms=60_000)
        if frame is None:  # overwritten during the copy: the caller would ask the connector
            continue
        sequence_mod_256 = (int(frame[0, 0, 0]) - background) % 256
        assert np.array_equal(frame, expected_frame(renders, sequence_mod_256)), "a torn frame was returned"
        sequences.add(sequence_mod_256)
    assert len(sequences) > 1, "the reader never saw the writer move on"
