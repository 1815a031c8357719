"""A Cell whose completion monitor runs a learned classifier says whether its model file can score.

The real API server: a cell worker heartbeats its Cell with ``CompletionReady`` beside
its health conditions, from the connector's own check of the model file (OpenCV's DNN
module loading the real ONNX file the project ships, or failing on a file that is not
one) and the agent's fence (a good model outside its completion directories is
refused); the operator's reading of the Cell then counts it faulted. A classifier
taken out of the Cell takes its condition with it.
"""

from __future__ import annotations

import contextlib
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


def unreachable_api() -> Any:
    """An API client for a port nobody listens on: the API server away (connection refused, at once)."""
    from armnet_testbed.procs import free_port

    configuration = client.Configuration()
    configuration.host = f"https://127.0.0.1:{free_port()}"
    configuration.verify_ssl = False
    configuration.retries = 0
    return client.ApiClient(configuration)


def classifier_cell(name: str, model: Path) -> dict[str, Any]:
    cell = a_cell(name)
    cell["spec"]["cameras"] = {"front": {"indexOrPath": 0, "width": 640, "height": 480, "fps": 30}}
    cell["spec"]["completion"] = {"camera": "front", "scorer": "classifier",
                                  "classifier": {"model": str(model), "inputSize": SHIPPED_CLASSIFIER_INPUT}}
    return cell


def completion_ready(k8s: Any, name: str, want: str | None, timeout: float = 60,
                     reason: str | None = None) -> dict[str, Any] | None:
    """The Cell's CompletionReady condition once its status is ``want`` (and its reason ``reason``, when
    given; None: once it is gone)."""
    deadline = time.monotonic() + timeout
    last: dict[str, Any] | None = None
    while time.monotonic() < deadline:
        conditions = (get(k8s, "cell", name).get("status") or {}).get("conditions") or []
        last = next((c for c in conditions if c["type"] == "CompletionReady"), None)
        if (last is None and want is None) or (
                last is not None and last["status"] == want and reason in (None, last["reason"])):
            return last
        time.sleep(0.2)
    raise AssertionError(f"CompletionReady={want} ({reason or 'any reason'}) never appeared on {name}; last: {last!r}")


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


def test_a_classifier_model_from_a_configmap_is_written_for_the_connector_and_follows_its_edits(k8s: Any) -> None:
    """The cell owner ships the model as a ConfigMap in the platform's namespace; the agent writes it to a
    file of its own that the checks (and the connector) read, takes an edit within its refresh, and says
    why when the ConfigMap is not a model or is gone."""
    import base64

    from armnet_node.completion_configmap import ConfigMapModels, resolved_cell
    from armnet_node.plan import completion_files_refused

    with contextlib.ExitStack() as cleanup:  # every step undone, in reverse, whichever one fails
        platform = k8s.create_namespace("armnet-platform")
        cleanup.callback(k8s.delete_namespace, platform)
        core = client.CoreV1Api(k8s.api_client())

        def ship(data: bytes) -> None:
            body = {"metadata": {"name": "reach"}, "binaryData": {"reach.onnx": base64.b64encode(data).decode()}}
            try:
                core.replace_namespaced_config_map("reach", platform, body)
            except client.exceptions.ApiException:
                core.create_namespaced_config_map(platform, body)

        ship(SHIPPED_CLASSIFIER.read_bytes())
        name = f"classifier-cm-{uuid.uuid4().hex[:8]}"
        spec = classifier_cell(name, SHIPPED_CLASSIFIER)
        spec["spec"]["completion"]["classifier"] = {
            "modelFrom": {"configMapKeyRef": {"name": "reach", "key": "reach.onnx"}}, "inputSize": SHIPPED_CLASSIFIER_INPUT}
        state_dir = Path(tempfile.mkdtemp(prefix="ant-", dir="/tmp"))
        cleanup.callback(shutil.rmtree, state_dir, ignore_errors=True)
        paths = HostPaths(state_dir, completion_dirs=())  # the agent's own models' directory only
        kube = AgentKube(k8s.api_client())
        models = ConfigMapModels(kube, platform, paths.completion_models_dir, refresh_s=0.5)
        created = apply(k8s, spec)
        cleanup.callback(client.CustomObjectsApi(k8s.api_client()).delete_cluster_custom_object,
                         GROUP, VERSION, CELLS, name)
        cell = resolved_cell(created, models)
        deps = RunnerDeps(kube=kube, launcher=None,  # type: ignore[arg-type]  # no job here
                          paths=paths, metrics=AgentMetrics(), link=NoLink(), uploads=None,  # type: ignore[arg-type]
                          completion_models=models)
        worker = CellWorker(cell, deps, WorkerSettings(heartbeat_period=1, telemetry=TelemetrySettings(0, 0))).start()
        cleanup.callback(worker.stop)

        condition = completion_ready(k8s, name, "True")
        assert condition is not None and condition["reason"] == "FilesUsable"
        assert cell.completion is not None and cell.completion.classifier is not None
        written = Path(str(cell.completion.classifier.model))
        assert written.parent == paths.completion_models_of(name)  # a folder of this cell's alone
        assert written.read_bytes() == SHIPPED_CLASSIFIER.read_bytes()
        assert written.stat().st_mode & 0o777 == 0o644  # a pod's connector reads it as its own uid
        assert completion_files_refused(cell, paths) is None

        ship(b"the wrong file, put in the ConfigMap by mistake")
        condition = completion_ready(k8s, name, "False", reason="FileUnusable")
        assert condition is not None
        assert f"the model of ConfigMap {platform}/reach, key reach.onnx" in condition["message"]
        assert "is not an ONNX model OpenCV can run" in condition["message"]
        wrong = resolved_cell(get(k8s, "cell", name), models).completion.classifier.model  # type: ignore[union-attr]
        assert wrong != str(written) and Path(str(wrong)).read_bytes().startswith(b"the wrong file")
        assert written.read_bytes() == SHIPPED_CLASSIFIER.read_bytes()  # a running job's model is never rewritten

        core.delete_namespaced_config_map("reach", platform)
        condition = completion_ready(k8s, name, "False", reason="ConfigMapUnusable")
        assert condition is not None
        assert f"ConfigMap {platform}/reach does not exist; create it there" in condition["message"]
        unresolved = resolved_cell(get(k8s, "cell", name), models)
        refused = completion_files_refused(unresolved, paths)
        assert refused is not None and "ConfigMap reach, key reach.onnx" in refused  # no job launches on it
        assert not models.pending(name)  # a definite problem: a bound job fails, saying it

        ship(SHIPPED_CLASSIFIER.read_bytes())  # fixed: the same model again, the same file
        completion_ready(k8s, name, "True", reason="FilesUsable")
        assert len(list(written.parent.glob("*.onnx"))) == 2  # the model, and the wrong file (kept: at most 3)

        # The API server away: the model written before stays the cell's; a cell with none waits, not fails.
        away = ConfigMapModels(AgentKube(unreachable_api()), platform, paths.completion_models_dir, refresh_s=0)
        assert away.resolve(parse_cell(get(k8s, "cell", name))).completion.classifier.model is None  # type: ignore[union-attr]
        assert away.pending(name) and "could not be read" in str(away.problem(name))
        models._reader = AgentKube(unreachable_api())  # the worker's own: its next reads fail
        time.sleep(1.0)
        kept = models.resolve(parse_cell(get(k8s, "cell", name)))
        assert kept.completion is not None and kept.completion.classifier is not None
        assert kept.completion.classifier.model == str(written) and models.problem(name) is None

        nowhere = ConfigMapModels(kube, None, paths.completion_models_dir)
        assert nowhere.resolve(parse_cell(get(k8s, "cell", name))).completion.classifier.model is None  # type: ignore[union-attr]
        assert "--config-namespace" in str(nowhere.problem(name)) and not nowhere.pending(name)

        worker.stop()
        models.retain([])  # the cell left this node: its models go
        assert not written.parent.exists()
