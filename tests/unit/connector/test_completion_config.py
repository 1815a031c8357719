"""A cell's ``completion`` settings: hostile or mistyped values are refused with what to fix."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from armnet_connector import CompletionConfig, ConnectorConfig
from armnet_connector.completion import build_scorer
from armnet_connector.scoring import ArucoRegionScorer, ColourRegionScorer
from armnet_connector.service_scorer import ServiceScorer
from pydantic import ValidationError

pytestmark = pytest.mark.unit


def a_completion(**overrides: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "camera": "front",
        "scorer": "region",
        "region": {"left": 0.7, "top": 0.1, "width": 0.1, "height": 0.1},
        "colour": {"hueMin": 170, "hueMax": 8},
        "consecutiveFrames": 3,
        "rateHz": 10,
    }
    data.update(overrides)
    return data


def test_a_colour_completion_loads_in_camel_case_and_builds_the_colour_scorer() -> None:
    config = CompletionConfig.model_validate(a_completion())
    assert (config.camera, config.consecutive_frames, config.rate_hz) == ("front", 3, 10)
    assert isinstance(build_scorer(config), ColourRegionScorer)


def test_an_aruco_completion_builds_the_aruco_scorer() -> None:
    config = CompletionConfig.model_validate(a_completion(colour=None, arucoId=7))
    assert isinstance(build_scorer(config), ArucoRegionScorer)


def test_a_service_completion_builds_the_service_scorer_with_its_defaults() -> None:
    config = CompletionConfig.model_validate(a_completion(
        scorer="service", region=None, colour=None, service={"url": "https://judge.lab/score"}))
    scorer = build_scorer(config)
    assert isinstance(scorer, ServiceScorer)
    assert (scorer.config.timeout_seconds, scorer.config.threshold, scorer.camera) == (0.5, 0.5, "front")


HOSTILE: list[tuple[str, dict[str, Any], str]] = [
    ("an empty region", {"region": {"left": 0.5, "top": 0.5, "width": 0, "height": 0.1}}, "region is empty"),
    ("a negative region", {"region": {"left": -0.2, "top": 0.1, "width": 0.1, "height": 0.1}}, "leaves the picture"),
    ("a region past the edge", {"region": {"left": 0.95, "top": 0.1, "width": 0.1, "height": 0.1}}, "leaves the picture"),
    ("a NaN region", {"region": {"left": float("nan"), "top": 0.1, "width": 0.1, "height": 0.1}}, "finite number"),
    ("a huge rate", {"rateHz": 10_000}, "give 0.5 to 30 frames per second"),
    ("a zero rate", {"rateHz": 0}, "give 0.5 to 30 frames per second"),
    ("an infinite rate", {"rateHz": float("inf")}, "finite number"),
    ("K = 0", {"consecutiveFrames": 0}, "consecutiveFrames is 0; give 1 to 300"),
    ("K = a million", {"consecutiveFrames": 1_000_000}, "give 1 to 300"),
    ("no object", {"colour": None}, "exactly one object"),
    ("two objects", {"arucoId": 3}, "exactly one object"),
    ("an ArUco id the dictionary lacks", {"colour": None, "arucoId": 50}, "holds ids 0 to 49"),
    ("an unknown dictionary", {"colour": None, "arucoId": 1, "arucoDictionary": "DICT_ARUCO_ORIGINAL"}, "use one of"),
    ("an unknown scorer", {"scorer": "vlm"}, "use one of ['region', 'service', 'classifier']"),
    ("a classifier scorer without its model", {"scorer": "classifier", "region": None, "colour": None},
     "needs completion.classifier (its model file)"),
    ("a classifier scorer with a region", {"scorer": "classifier", "classifier": {"model": "/m/reach.onnx"}},
     "scores with its model alone: leave out region, colour and arucoId"),
    ("a region scorer given a classifier", {"classifier": {"model": "/m/reach.onnx"}}, "is for scorer classifier"),
    ("a relative model path", {"scorer": "classifier", "region": None, "colour": None,
                               "classifier": {"model": "models/reach.onnx"}}, "give the absolute path of a file on the robot host"),
    ("a model path climbing out", {"scorer": "classifier", "region": None, "colour": None,
                                   "classifier": {"model": "/var/lib/armnet/../../etc/x.onnx"}},
     "give a normalized absolute path"),
    ("a model that is not .onnx", {"scorer": "classifier", "region": None, "colour": None,
                                   "classifier": {"model": "/var/lib/armnet/reach.pt"}}, "ending in .onnx"),
    ("a relative token file", {"scorer": "service", "region": None, "colour": None,
                               "service": {"url": "http://j:1/s", "tokenFile": "secrets/judge"}},
     "completion.service.tokenFile 'secrets/judge': give the absolute path of a file on the robot host"),
    ("a token file climbing out", {"scorer": "service", "region": None, "colour": None,
                                   "service": {"url": "http://j:1/s", "tokenFile": "/var/lib/../../etc/shadow"}},
     "give a normalized absolute path"),
    ("a classifier input of 4 pixels", {"scorer": "classifier", "region": None, "colour": None,
                                        "classifier": {"model": "/m/reach.onnx", "inputSize": 4}},
     "inputSize is 4; give 16 to 512 pixels"),
    ("a NaN classifier threshold", {"scorer": "classifier", "region": None, "colour": None,
                                    "classifier": {"model": "/m/reach.onnx", "threshold": float("nan")}},
     "finite number"),
    ("a classifier with two models", {"scorer": "classifier", "region": None, "colour": None, "classifier": {
        "model": "/m/reach.onnx", "modelFrom": {"configMapKeyRef": {"name": "reach", "key": "reach.onnx"}}}},
     "needs exactly one model: model (a file on the robot host) or modelFrom.configMapKeyRef"),
    ("a classifier with no model", {"scorer": "classifier", "region": None, "colour": None,
                                    "classifier": {"inputSize": 96}}, "needs exactly one model"),
    ("a model ConfigMap that is no name", {"scorer": "classifier", "region": None, "colour": None, "classifier": {
        "modelFrom": {"configMapKeyRef": {"name": "../etc", "key": "reach.onnx"}}}}, "configMapKeyRef.name"),
    ("a model key that is not .onnx", {"scorer": "classifier", "region": None, "colour": None, "classifier": {
        "modelFrom": {"configMapKeyRef": {"name": "reach", "key": "reach.pt"}}}}, "configMapKeyRef.key"),
    ("a region scorer without its region", {"region": None}, "scorer region needs completion.region"),
    ("a region scorer given a service", {"service": {"url": "http://judge.lab:8080/score"}}, "is for scorer service"),
    ("a service scorer without its service", {"scorer": "service"}, "needs completion.service (its url)"),
    ("a service scorer with a region", {"scorer": "service", "service": {"url": "http://judge.lab:8080/score"}},
     "leave out region, colour and arucoId"),
    ("a service on another scheme", {"scorer": "service", "region": None, "colour": None,
                                     "service": {"url": "file:///etc/passwd"}}, "String should match pattern"),
    ("a service slower than the monitor waits", {"scorer": "service", "region": None, "colour": None,
                                                 "service": {"url": "http://j:1/s", "timeoutSeconds": 5}},
     "give 0.05 to 1 seconds"),
    ("a threshold past 1", {"scorer": "service", "region": None, "colour": None,
                            "service": {"url": "http://j:1/s", "threshold": 2}}, "less than or equal to 1"),
    ("a hue past 179", {"colour": {"hueMin": 0, "hueMax": 200}}, "colour.hueMax\n  Input should be less than or equal to 179"),
    ("a reversed saturation range", {"colour": {"hueMin": 0, "hueMax": 8, "saturationMin": 200,
                                                "saturationMax": 100}}, "must not exceed"),
    ("zero pixels", {"minPixels": 0}, "give 1 to 10000000 pixels"),
    ("a typo in a field", {"rate": 5}, "rate"),
]


@pytest.mark.parametrize(("case", "change", "says"), HOSTILE, ids=[c[0] for c in HOSTILE])
def test_a_hostile_completion_is_refused_saying_what_to_fix(case: str, change: dict[str, Any], says: str) -> None:
    with pytest.raises(ValidationError) as raised:
        CompletionConfig.model_validate(a_completion(**change))
    assert says in str(raised.value)


def test_the_connector_refuses_a_completion_on_a_camera_the_cell_lacks(
    cell_config: Callable[..., ConnectorConfig],
) -> None:
    with pytest.raises(ValidationError) as raised:
        cell_config(None, completion=a_completion(camera="wrist"))
    assert "completion.camera 'wrist' is not a camera of this cell; name one of ['front']" in str(raised.value)


def test_a_cell_without_completion_has_no_monitor_settings(cell_config: Callable[..., ConnectorConfig]) -> None:
    assert cell_config(None).completion is None
    assert cell_config(None, completion=a_completion()).completion == CompletionConfig.model_validate(a_completion())


def test_a_classifier_from_a_configmap_reads_no_host_file_until_the_agent_wrote_one() -> None:
    from armnet_core.cell_completion import host_files

    completion = CompletionConfig.model_validate(a_completion(scorer="classifier", region=None, colour=None, classifier={
        "modelFrom": {"configMapKeyRef": {"name": "reach", "key": "reach.onnx"}}, "inputSize": 96}))
    assert completion.classifier is not None and host_files(completion) == ()
    from armnet_connector.classifier_scorer import model_problem

    assert "only a node agent in the cluster reads" in str(model_problem(completion.classifier))
    written = completion.classifier.with_model_file("/var/lib/armnet/cache/completion-models/c/ab.onnx")
    assert (written.model, written.model_from, written.input_size) == (
        "/var/lib/armnet/cache/completion-models/c/ab.onnx", None, 96)
