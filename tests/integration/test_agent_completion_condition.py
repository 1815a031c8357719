"""A Cell whose completion monitor runs a learned classifier says whether its model file can score.

The real API server: a cell worker heartbeats its Cell with ``CompletionReady`` beside
its health conditions, from the connector's own check of the model file (OpenCV's DNN
module loading the real ONNX file the project ships, or failing on a file that is not
one) and the agent's fence (a good model outside its completion directories is
refused); the operator's reading of the Cell then counts it faulted. A classifier
taken out of the Cell takes its condition with it.
"""

from __future__ import annotations

import shutil
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import pytest
from armnet_core.api import CELLS, GROUP, VERSION
from armnet_node.kube import AgentKube
from armnet_node.metrics import AgentMetrics
from armnet_node.model import parse_cell
from armnet_node.plan import HostPaths
from armnet_node.publish import NoLink
from armnet_node.runner import RunnerDeps
from armnet_node.telemetry import TelemetrySettings
from armnet_node.worker import CellWorker, WorkerSettings
from armnet_operator.parsing import parse_cell as operator_parse_cell
from armnet_sim.scene_samples import SHIPPED_CLASSIFIER, SHIPPED_CLASSIFIER_INPUT
from kubernetes import client

from tests.support.fms_objects import a_cell, apply, get

pytestmark = pytest.mark.integration


def classifier_cell(name: str, model: Path) -> dict[str, Any]:
    cell = a_cell(name)
    cell["spec"]["cameras"] = {"front": {"indexOrPath": 0, "width": 640, "height": 480, "fps": 30}}
    cell["spec"]["completion"] = {"camera": "front", "scorer": "classifier",
                                  "classifier": {"model": str(model), "inputSize": SHIPPED_CLASSIFIER_INPUT}}
    return cell


def completion_ready(k8s: Any, name: str, want: str | None, timeout: float = 60) -> dict[str, Any] | None:
    """The Cell's CompletionReady condition once its status is ``want`` (None: once it is gone)."""
    deadline = time.monotonic() + timeout
    last: dict[str, Any] | None = None
    while time.monotonic() < deadline:
        conditions = (get(k8s, "cell", name).get("status") or {}).get("conditions") or []
        last = next((c for c in conditions if c["type"] == "CompletionReady"), None)
        if (last is None and want is None) or (last is not None and last["status"] == want):
            return last
        time.sleep(0.2)
    raise AssertionError(f"CompletionReady={want} never appeared on {name}; last: {last!r}")


def test_a_cell_whose_model_is_not_a_model_is_faulted_saying_why_until_the_file_is_fixed(k8s: Any) -> None:
    models = Path(tempfile.mkdtemp(prefix="armnet-models-"))
    model = models / "reach.onnx"
    model.write_text("a model file that was copied half-way, or the wrong file altogether")
    name = f"classifier-{uuid.uuid4().hex[:8]}"
    cell = parse_cell(apply(k8s, classifier_cell(name, model)))
    state_dir = Path(tempfile.mkdtemp(prefix="ant-", dir="/tmp"))
    paths = HostPaths(state_dir, completion_dirs=(str(models),))
    deps = RunnerDeps(kube=AgentKube(k8s.api_client()), launcher=None,  # type: ignore[arg-type]  # no job here
                      paths=paths, metrics=AgentMetrics(), link=NoLink(), uploads=None)
    no_telemetry = TelemetrySettings(servo_hz=0, frame_fps=0)
    worker = CellWorker(cell, deps, WorkerSettings(heartbeat_period=1, telemetry=no_telemetry)).start()
    try:
        condition = completion_ready(k8s, name, "False")
        assert condition is not None and condition["reason"] == "FileUnusable"
        assert f"the model file {model} is not an ONNX model OpenCV can run" in condition["message"]
        assert "CompletionReady" in operator_parse_cell(get(k8s, "cell", name)).failing_conditions

        shutil.copyfile(SHIPPED_CLASSIFIER, model)  # the cell owner puts the right file in place
        condition = completion_ready(k8s, name, "True")
        assert condition is not None and condition["reason"] == "FilesUsable"
        assert "CompletionReady" not in operator_parse_cell(get(k8s, "cell", name)).failing_conditions

        objects = client.CustomObjectsApi(k8s.api_client())
        elsewhere = Path(tempfile.mkdtemp(prefix="armnet-elsewhere-")) / "reach.onnx"
        shutil.copyfile(SHIPPED_CLASSIFIER, elsewhere)  # a good model, outside the agent's directories
        objects.patch_cluster_custom_object(GROUP, VERSION, CELLS, name, {"spec": {"completion": {
            "classifier": {"model": str(elsewhere)}}}})
        condition = completion_ready(k8s, name, "False")
        assert condition is not None and f"{elsewhere} is outside the directories" in condition["message"]
        shutil.rmtree(elsewhere.parent, ignore_errors=True)

        objects.patch_cluster_custom_object(GROUP, VERSION, CELLS, name, {"spec": {"completion": None}})
        assert completion_ready(k8s, name, None) is None
    finally:
        worker.stop()
        shutil.rmtree(state_dir, ignore_errors=True)
        shutil.rmtree(models, ignore_errors=True)
        client.CustomObjectsApi(k8s.api_client()).delete_cluster_custom_object(GROUP, VERSION, CELLS, name)
