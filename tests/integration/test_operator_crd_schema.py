"""The CRDs on the real API server: defaults, readable rejections, CEL immutability, examples."""

from __future__ import annotations

import json
import subprocess
import uuid
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_core.api import GROUP, ROBOTJOBS, VERSION
from armnet_node import rollout_history as rh
from kubernetes import client
from kubernetes.client.exceptions import ApiException

pytestmark = pytest.mark.integration

EXAMPLES = Path(__file__).resolve().parents[2] / "crds" / "examples"


def job(namespace: str, name: str | None = None, **spec: Any) -> dict[str, Any]:
    body = {"image": "registry.example.com/team/pick:1.0", "embodiment": "lerobot/so-101", **spec}
    return {"apiVersion": "armnet.io/v1alpha1", "kind": "RobotJob",
            "metadata": {"name": name or f"j-{uuid.uuid4().hex[:6]}", "namespace": namespace}, "spec": body}


def apply(k8s: Any, doc: dict[str, Any], check: bool = True) -> subprocess.CompletedProcess[str]:
    return k8s.kubectl("apply", "-f", "-", input=yaml.safe_dump(doc), check=check)


def rejected(k8s: Any, doc: dict[str, Any]) -> str:
    result = apply(k8s, doc, check=False)
    assert result.returncode != 0, f"accepted: {doc}"
    return result.stderr


def get(k8s: Any, namespace: str, name: str) -> dict[str, Any]:
    return json.loads(k8s.kubectl("get", "robotjob", name, "-n", namespace, "-o", "json").stdout)


def test_defaults_fill_in_the_optional_fields(k8s: Any, namespace: str) -> None:
    apply(k8s, job(namespace, "plain"))
    spec = get(k8s, namespace, "plain")["spec"]
    assert (spec["timeoutSeconds"], spec["priority"], spec["cancel"], spec["detach"]) == (120, 0, False, False)
    assert spec["args"] == {} and spec["secrets"] == {}


@pytest.mark.parametrize(("spec", "says"), [
    ({"timeoutSeconds": 0}, "spec.timeoutSeconds: Invalid value: 0: spec.timeoutSeconds in body should be greater than or equal to 1"),
    ({"embodiment": ""}, "spec.embodiment"),
    ({"image": "Not An Image!"}, "image must be an image reference like"),
    ({"secrets": {"1BAD": "token"}}, "secrets keys must be environment variable names"),
    ({"priority": 5000}, "spec.priority"),
])
def test_bad_specs_are_rejected_with_a_readable_message(k8s: Any, namespace: str, spec: dict[str, Any], says: str) -> None:
    assert says in rejected(k8s, job(namespace, **spec))


def test_embodiment_is_required(k8s: Any, namespace: str) -> None:
    doc = job(namespace)
    del doc["spec"]["embodiment"]
    assert "spec.embodiment: Required value" in rejected(k8s, doc)


def test_plausible_image_references_are_accepted(k8s: Any, namespace: str) -> None:
    for image in ("localhost/pick:dev", "my-image:latest", "ghcr.io/org/team/pick:1.2.3",
                  "registry.example.com:5000/x/y@sha256:" + "a" * 64):
        apply(k8s, job(namespace, image=image))


def test_the_spec_is_immutable_after_creation(k8s: Any, namespace: str) -> None:
    apply(k8s, job(namespace, "fixed"))
    changed = job(namespace, "fixed", image="registry.example.com/team/other:2.0")
    assert "spec is immutable after creation except cancel" in rejected(k8s, changed)
    with_task = job(namespace, "fixed", task="fold")
    assert "spec is immutable after creation" in rejected(k8s, with_task)


def test_cancel_can_be_set_but_not_undone(k8s: Any, namespace: str) -> None:
    apply(k8s, job(namespace, "stop-me"))
    apply(k8s, job(namespace, "stop-me", cancel=True))
    assert "cancel cannot be undone" in rejected(k8s, job(namespace, "stop-me", cancel=False))


def test_priority_changes_while_queued_but_not_once_bound(k8s: Any, namespace: str) -> None:
    apply(k8s, job(namespace, "prio"))
    k8s.kubectl("patch", "robotjob", "prio", "-n", namespace, "--subresource=status", "--type=merge",
                "-p", '{"status":{"phase":"queued"}}')
    apply(k8s, job(namespace, "prio", priority=7))
    assert get(k8s, namespace, "prio")["spec"]["priority"] == 7
    k8s.kubectl("patch", "robotjob", "prio", "-n", namespace, "--subresource=status", "--type=merge",
                "-p", '{"status":{"phase":"running","cellName":"c"}}')
    assert "spec.priority can only change while the job is queued" in rejected(k8s, job(namespace, "prio", priority=9))


def test_a_bimanual_cell_must_name_both_arms(k8s: Any) -> None:
    cell = {"apiVersion": "armnet.io/v1alpha1", "kind": "Cell", "metadata": {"name": f"bi-{uuid.uuid4().hex[:6]}"},
            "spec": {"embodiment": "lerobot/bimanual_so101", "nodeName": "h", "arms": {"left": {"port": "/dev/a"}}}}
    assert "a bimanual cell needs spec.arms.left and spec.arms.right" in rejected(k8s, cell)


def test_the_examples_are_valid(k8s: Any) -> None:
    paths = sorted(EXAMPLES.glob("*.yaml"))
    assert {p.name for p in paths} >= {"cell-so101.yaml", "robotjob.yaml"}, paths  # a moved folder must not pass
    for path in paths:
        k8s.kubectl("apply", "--dry-run=server", "-f", str(path), *(["-n", "default"] if "job" in path.name else []))


def test_kubectl_get_armnet_lists_jobs_and_cells_with_their_columns(k8s: Any, namespace: str) -> None:
    apply(k8s, job(namespace, "shown", task="fold"))
    out = k8s.kubectl("get", "armnet", "-n", namespace).stdout
    assert "robotjob.armnet.io/shown" in out
    header = k8s.kubectl("get", "rj", "-n", namespace).stdout.splitlines()[0].split()
    assert header == ["NAME", "PHASE", "CELL", "EMBODIMENT", "AGE"]
    name = f"shown-{uuid.uuid4().hex[:6]}"
    apply(k8s, {"apiVersion": "armnet.io/v1alpha1", "kind": "Cell", "metadata": {"name": name},
                "spec": {"embodiment": "lerobot/so-101", "task": "fold", "nodeName": "host-a", "simulated": True}})
    try:
        lines = k8s.kubectl("get", "cell", name).stdout.splitlines()
    finally:
        k8s.kubectl("delete", "cell", name, "--wait=false")
    assert lines[0].split() == ["NAME", "EMBODIMENT", "TASK", "PHASE", "JOB", "NODE", "AGE"]
    assert lines[1].split()[:4] == [name, "lerobot/so-101", "fold", "host-a"]  # no status yet: PHASE, JOB blank


def test_the_rollout_history_holds_the_agents_fifty_newest_and_refuses_more(k8s: Any, namespace: str) -> None:
    history: rh.History = ()
    moment = datetime(2026, 3, 1, tzinfo=UTC)
    for index in range(1, rh.MAX_ENTRIES + 3):
        history = rh.apply(rh.apply(history, rh.Begun(index, 60, moment)), rh.Marked(index % 2 == 0, "ana", moment))
    rows = rh.as_status(history)
    apply(k8s, job(namespace, "history"))
    custom = client.CustomObjectsApi(k8s.api_client())
    args = (GROUP, VERSION, namespace, ROBOTJOBS, "history")
    custom.patch_namespaced_custom_object_status(*args, {"status": {"rollouts": rows}})
    assert get(k8s, namespace, "history")["status"]["rollouts"] == rows
    with pytest.raises(ApiException) as refused:
        custom.patch_namespaced_custom_object_status(*args, {"status": {"rollouts": [*rows, rows[-1]]}})
    assert refused.value.status == 422 and "status.rollouts" in str(refused.value.body)


def a_cell(completion: dict[str, Any] | None) -> dict[str, Any]:
    spec: dict[str, Any] = {"embodiment": "lerobot/so-101", "nodeName": "h", "simulated": True,
                            "cameras": {"front": {"indexOrPath": 0}}}
    if completion is not None:
        spec["completion"] = completion
    return {"apiVersion": "armnet.io/v1alpha1", "kind": "Cell",
            "metadata": {"name": f"c-{uuid.uuid4().hex[:6]}"}, "spec": spec}


def a_completion(**change: Any) -> dict[str, Any]:
    body: dict[str, Any] = {"camera": "front", "region": {"left": 0.7, "top": 0.1, "width": 0.1, "height": 0.1},
                            "colour": {"hueMin": 170, "hueMax": 8}}
    body.update(change)
    return {k: v for k, v in body.items() if v is not None}


def test_a_cell_with_a_completion_monitor_is_accepted_with_its_defaults(k8s: Any) -> None:
    cell = a_cell(a_completion())
    apply(k8s, cell)
    try:
        stored = json.loads(k8s.kubectl("get", "cell", cell["metadata"]["name"], "-o", "json").stdout)
        completion = stored["spec"]["completion"]
        assert (completion["scorer"], completion["consecutiveFrames"], completion["rateHz"]) == ("region", 3, 5)
    finally:
        k8s.kubectl("delete", "cell", cell["metadata"]["name"], "--wait=false")


@pytest.mark.parametrize(("scorer", "setting", "defaults"), [
    ("service", {"url": "http://judge.lab.internal:8080/score"}, {"timeoutSeconds": 0.5, "threshold": 0.5}),
    ("classifier", {"model": "/var/lib/armnet/models/reach.onnx"}, {"threshold": 0.5, "inputSize": 64}),
    ("classifier", {"modelFrom": {"configMapKeyRef": {"name": "reach-classifier", "key": "reach.onnx"}}},
     {"threshold": 0.5, "inputSize": 64}),
])
def test_a_cell_with_a_scoring_service_or_a_classifier_is_accepted_with_its_defaults(
    k8s: Any, scorer: str, setting: dict[str, Any], defaults: dict[str, Any],
) -> None:
    cell = a_cell(a_completion(scorer=scorer, region=None, colour=None, **{scorer: setting}))
    apply(k8s, cell)
    try:
        stored = json.loads(k8s.kubectl("get", "cell", cell["metadata"]["name"], "-o", "json").stdout)
        assert stored["spec"]["completion"][scorer] == {**setting, **defaults}
    finally:
        k8s.kubectl("delete", "cell", cell["metadata"]["name"], "--wait=false")


SERVICE = {"url": "http://judge.lab.internal:8080/score"}
CLASSIFIER = {"model": "/var/lib/armnet/models/reach.onnx"}


@pytest.mark.parametrize(("completion", "says"), [
    (a_completion(region=None), "scorer region needs region"),
    (a_completion(scorer="service", region=None, colour=None), "scorer service needs service"),
    (a_completion(scorer="service", service=SERVICE), "a service or classifier scorer scores alone"),
    (a_completion(service=SERVICE), "service and classifier each belong to their own scorer"),
    (a_completion(scorer="classifier", region=None, colour=None), "scorer classifier needs classifier"),
    (a_completion(scorer="service", region=None, colour=None, service={**SERVICE, "tokenFile": "judge-token"}),
     "spec.completion.service.tokenFile"),
    (a_completion(scorer="classifier", classifier=CLASSIFIER), "a service or classifier scorer scores alone"),
    (a_completion(classifier=CLASSIFIER), "service and classifier each belong to their own scorer"),
    (a_completion(scorer="service", region=None, colour=None, service=SERVICE, classifier=CLASSIFIER),
     "service and classifier each belong to their own scorer"),
    (a_completion(scorer="classifier", region=None, colour=None, classifier={"model": "models/reach.onnx"}),
     "spec.completion.classifier.model"),
    (a_completion(scorer="classifier", region=None, colour=None, classifier={**CLASSIFIER, "inputSize": 4}),
     "spec.completion.classifier.inputSize"),
    (a_completion(scorer="classifier", region=None, colour=None, classifier={
        **CLASSIFIER, "modelFrom": {"configMapKeyRef": {"name": "reach", "key": "reach.onnx"}}}),
     "spec.completion.classifier needs exactly one model"),
    (a_completion(scorer="classifier", region=None, colour=None, classifier={"inputSize": 96}),
     "spec.completion.classifier needs exactly one model"),
    (a_completion(scorer="classifier", region=None, colour=None, classifier={
        "modelFrom": {"configMapKeyRef": {"name": "reach", "key": "../reach.pt"}}}),
     "spec.completion.classifier.modelFrom.configMapKeyRef.key"),
    (a_completion(scorer="classifier", region=None, colour=None,
                  classifier={"model": "/var/lib/armnet/models/../../../etc/x.onnx"}), "give a normalized absolute path"),
    (a_completion(scorer="service", region=None, colour=None,
                  service={**SERVICE, "tokenFile": "/var/lib/armnet/secrets//../token"}), "give a normalized absolute path"),
    (a_completion(scorer="service", region=None, colour=None, service={"url": "file:///etc/passwd"}),
     "spec.completion.service.url"),
    (a_completion(scorer="service", region=None, colour=None, service={**SERVICE, "timeoutSeconds": 5}),
     "spec.completion.service.timeoutSeconds"),
    (a_completion(camera="wrist"), "spec.completion.camera must name one of spec.cameras"),
    (a_completion(region={"left": 0.5, "top": 0.5, "width": 0, "height": 0.1}), "spec.completion.region.width"),
    (a_completion(region={"left": -0.1, "top": 0.5, "width": 0.1, "height": 0.1}), "spec.completion.region.left"),
    (a_completion(region={"left": 0.95, "top": 0.5, "width": 0.1, "height": 0.1}), "spec.completion.region leaves the picture"),
    (a_completion(rateHz=10000), "spec.completion.rateHz"),
    (a_completion(consecutiveFrames=0), "spec.completion.consecutiveFrames"),
    (a_completion(arucoId=3), "exactly one object to look for"),
    (a_completion(colour=None), "exactly one object to look for"),
    (a_completion(colour=None, arucoId=60), "spec.completion.arucoId is not in its dictionary"),
    (a_completion(scorer="vlm"), "spec.completion.scorer"),
    (a_completion(colour={"hueMin": 0, "hueMax": 8, "valueMin": 200, "valueMax": 10}), "must not exceed"),
])
def test_a_hostile_completion_is_rejected_saying_what_to_fix(k8s: Any, completion: dict[str, Any], says: str) -> None:
    assert says in rejected(k8s, a_cell(completion))
