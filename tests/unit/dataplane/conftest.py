"""Fixtures for the data-plane tests: a camera cell's connector on real sockets, frames in a tmpfs."""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterator
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
from armnet_connector import Connector, ConnectorConfig, LocalOperatorInputs
from armnet_connector.hardware import simulated_camera_factory

POSE = {
    "shoulder_pan": 12.0, "shoulder_lift": -30.0, "elbow_flex": 45.0,
    "wrist_flex": 10.0, "wrist_roll": 0.0, "gripper": 20.0,
}
"""The joint state every simulated camera here draws: the same state gives the same picture."""


def fixed_pose() -> dict[str, float]:
    return dict(POSE)


def camera_cell_config(fps: int = 30) -> ConnectorConfig:
    calibration = Path(str(resources.files("armnet_sim.data").joinpath("so101.json")))
    return ConnectorConfig.model_validate(
        {
            "arms": {"arm": {"port": "/dev/null-armnet-test", "calibrationFile": str(calibration), "safetyLimit": 30}},
            "cameras": {"front": {"indexOrPath": 0, "fps": fps, "width": 640, "height": 480}},
            "simulated": True,
        }
    )


@pytest.fixture
def socket_dir() -> Iterator[Path]:
    """A socket directory on a tmpfs, as a pod's ``emptyDir: {medium: Memory}``."""
    path = Path(tempfile.mkdtemp(prefix="adp-", dir="/dev/shm"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def make_connector(socket_dir: Path) -> Iterator[Callable[..., Connector]]:
    started: list[Connector] = []

    def make(fps: int = 30, **kwargs: Any) -> Connector:
        kwargs.setdefault("inputs", LocalOperatorInputs())
        kwargs.setdefault("camera_factory", simulated_camera_factory(source=fixed_pose))
        connector = Connector(camera_cell_config(fps), socket_dir, **kwargs)
        started.append(connector)
        return connector

    yield make
    for connector in started:
        connector.stop()
