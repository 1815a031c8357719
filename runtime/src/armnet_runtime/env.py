"""Environment variable keys the platform injects into a job's container.

The single source of truth shared by the agent (which sets them) and the SDK
(which reads them). Values are part of the public contract: never rename one.
"""

from __future__ import annotations

JOB_ID = "ARMNET_JOB_ID"
EMBODIMENT = "ARMNET_EMBODIMENT"
TASK = "ARMNET_TASK"
TIMEOUT_SECONDS = "ARMNET_TIMEOUT_SECONDS"
ARGS = "ARMNET_ARGS"
CELL_CONFIG = "ARMNET_CELL_CONFIG"
CELL_SOCKET = "ARMNET_CELL_SOCKET"
OPERATOR_CALL_ENDPOINT = "ARMNET_OPERATOR_CALL_ENDPOINT"
LOCAL_CONTROL_ENDPOINT = "ARMNET_LOCAL_CONTROL_ENDPOINT"
LOCAL_CONTAINER = "ARMNET_LOCAL_CONTAINER"
ROBOT_ID = "ARMNET_ROBOT_ID"
CALIBRATION_DIR = "ARMNET_CALIBRATION_DIR"
CALIBRATION_FILE_PATH = "ARMNET_CALIBRATION_FILE_PATH"
CACHE_HOME = "REMOTEROBOT_CACHE_HOME"
VOLUME_HOME = "REMOTEROBOT_VOLUME_HOME"
HF_HOME = "HF_HOME"
OUTPUT_DIR = "ARMNET_OUTPUT_DIR"
"""The job's output directory: what the job writes here is uploaded to the object store when it ends."""
HF_LEROBOT_HOME = "HF_LEROBOT_HOME"
"""LeRobot's dataset root, inside the output directory: a recorded dataset is kept with the job."""
SECRETS = "ARMNET_SECRETS"
LEROBOT_TOOLS = "ARMNET_LEROBOT_TOOLS"
"""``remote`` in a job's container (and in no other process): LeRobot's own commands started in it
reach the cell through the connector (``armnet_runtime.lerobot.in_job``)."""
CALIBRATION_JOBS = "ARMNET_CALIBRATION_JOBS"
"""``1`` when the cell's owner allows calibration jobs (``spec.allowCalibrationJobs``), else ``0``."""

RERUN_QUEUE_MAXSIZE = "ARMNET_RERUN_QUEUE_MAXSIZE"
"""Bound of the Rerun streamer's queue (oldest frames are dropped beyond it)."""
