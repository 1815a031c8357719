"""The ``classifier`` scorer: the shipped model on rendered frames, and every way a model file can be unusable.

Real parts: the ONNX file this project trains (``bench/train_completion_classifier.py``),
OpenCV's DNN module that the connector runs it in, the simulator's renderer. A bad
model is a clear error on every score and on the cell (``CompletionReady``), never a
wedged monitor.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from armnet_connector.classifier_scorer import (
    ClassifierModelError,
    ClassifierScorer,
    classifier_input,
    model_problem,
    sigmoid,
)
from armnet_connector.completion import build_scorer
from armnet_core.cell_completion import MAX_MODEL_BYTES, ClassifierConfig, CompletionConfig
from armnet_node.completion_model import CompletionFilesCheck, files_problem
from armnet_node.health import completion_condition
from armnet_sim.render import TARGET_POSE
from armnet_sim.scene_samples import (
    SHIPPED_CLASSIFIER,
    SHIPPED_CLASSIFIER_INPUT,
    frame_of,
    no_scene,
    samples,
)

pytestmark = pytest.mark.unit


def shipped(**overrides: Any) -> ClassifierConfig:
    return ClassifierConfig(**{"model": str(SHIPPED_CLASSIFIER.resolve()), "input_size": SHIPPED_CLASSIFIER_INPUT,
                               **overrides})


def test_the_shipped_model_scores_the_arm_on_the_target_a_hit_and_off_it_a_miss() -> None:
    scorer = ClassifierScorer(shipped())
    on = scorer.score(frame_of(dict(TARGET_POSE)))
    assert on.hit and on.score >= 0.5 and "the classifier scored" in on.detail
    for miss in ({**TARGET_POSE, "elbow_flex": TARGET_POSE["elbow_flex"] - 15.0},
                 {"shoulder_lift": -30.0, "elbow_flex": -20.0, "wrist_flex": 10.0}):
        assert not scorer.score(frame_of(miss)).hit, miss


def test_the_shipped_model_never_scores_a_picture_of_no_task_complete() -> None:
    # A pod's simulated camera without the simulator's state draws "no arm attached": a model
    # trained on arm pictures alone took that for a success (e2e on the pod launcher).
    scorer = ClassifierScorer(shipped())
    rng = np.random.default_rng(7)
    for _ in range(12):
        assert not scorer.score(no_scene(rng)).hit


def test_the_shipped_model_tells_successes_from_near_misses_under_changed_light() -> None:
    # A small held-out sample here; bench/completion_accuracy.py measures 800 against the 0.95 targets.
    pictures = samples(4242, 60)
    scorer = build_scorer(CompletionConfig.model_validate(
        {"camera": "front", "scorer": "classifier", "classifier": shipped().model_dump(by_alias=True)}))
    right = sum(scorer.score(p.image).hit == p.complete for p in pictures)
    assert right >= 0.9 * len(pictures), f"{right} of {len(pictures)} right"


def test_the_input_is_rgb_0_to_1_in_the_models_square() -> None:
    frame = np.zeros((48, 64, 3), np.uint8)
    frame[..., 0] = 255  # blue in BGR
    blob = classifier_input(frame, 32)
    assert blob.shape == (1, 3, 32, 32) and blob.dtype == np.float32
    assert blob[0, 2].min() == 1.0 and blob[0, 0].max() == 0.0  # channel 2 is blue in RGB order


def test_sigmoid_does_not_overflow() -> None:
    assert sigmoid(-1000.0) == 0.0 and sigmoid(1000.0) == 1.0 and sigmoid(0.0) == 0.5


def bad_model(path: Path) -> ClassifierConfig:
    return ClassifierConfig(model=str(path))


def unusable(tmp_path: Path) -> list[tuple[str, ClassifierConfig, str]]:
    text = tmp_path / "text.onnx"
    text.write_bytes(b"this is not a model at all\n" * 40)
    empty = tmp_path / "empty.onnx"
    empty.write_bytes(b"")
    huge = tmp_path / "huge.onnx"
    with huge.open("wb") as file:  # sparse: 2 GB that take no disk
        file.truncate(2 << 30)
    directory = tmp_path / "dir.onnx"
    directory.mkdir()
    return [
        ("not a model", bad_model(text), "is not an ONNX model OpenCV can run"),
        ("empty", bad_model(empty), "is empty"),
        ("2 GB", bad_model(huge), f"2,048 MiB, over the {MAX_MODEL_BYTES >> 20} MiB"),
        ("a directory", bad_model(directory), "is not a regular file"),
        ("missing", bad_model(tmp_path / "nowhere.onnx"), "does not exist on this robot host"),
        ("the wrong input size", shipped(input_size=64), "check completion.classifier.inputSize"),
    ]


def test_every_unusable_model_is_refused_saying_why_on_each_score_and_in_the_cells_condition(tmp_path: Path) -> None:
    frame = frame_of(dict(TARGET_POSE))
    for case, config, says in unusable(tmp_path):
        scorer = ClassifierScorer(config)
        for _ in range(2):  # loaded once; the same error every time after
            with pytest.raises(ClassifierModelError) as raised:
                scorer.score(frame)
            assert says in str(raised.value), case
        problem = model_problem(config)
        assert problem is not None and says in problem, case
        condition = completion_condition(problem)
        assert (condition.type, condition.status, condition.reason) == ("CompletionReady", "False", "FileUnusable")
        assert says in condition.message and "no job is bound to this cell" in condition.message
    assert completion_condition(model_problem(shipped())).status == "True"


def classifier_completion(path: Path) -> CompletionConfig:
    return CompletionConfig.model_validate({"camera": "front", "scorer": "classifier",
                                            "classifier": {"model": str(path), "inputSize": SHIPPED_CLASSIFIER_INPUT}})


def test_the_agents_check_loads_the_model_again_only_when_the_file_changes(tmp_path: Path) -> None:
    path = tmp_path / "reach.onnx"
    path.write_bytes(b"not yet a model")
    check = CompletionFilesCheck(dirs=(str(tmp_path),))
    assert "is not an ONNX model" in (check.problem(classifier_completion(path)) or "")
    assert "is not an ONNX model" in (check.problem(classifier_completion(path)) or "") and check.checks == 1
    path.write_bytes(SHIPPED_CLASSIFIER.read_bytes())  # the cell owner copies the right file in
    os.utime(path, ns=(time.time_ns(), time.time_ns() + 1_000_000))
    assert check.problem(classifier_completion(path)) is None
    assert check.checks == 2


def test_the_agents_check_refuses_files_outside_its_directories_links_and_what_the_connector_cannot_read(
    tmp_path: Path,
) -> None:
    allowed = tmp_path / "models"
    allowed.mkdir()
    outside = tmp_path / "reach.onnx"
    outside.write_bytes(SHIPPED_CLASSIFIER.read_bytes())
    link = allowed / "link.onnx"
    link.symlink_to(outside)  # inside by its name, outside in truth
    private = allowed / "private.onnx"
    private.write_bytes(SHIPPED_CLASSIFIER.read_bytes())
    private.chmod(0o600)  # root's alone: the pod's connector (uid 65532) could not read it
    fine = allowed / "reach.onnx"
    fine.write_bytes(SHIPPED_CLASSIFIER.read_bytes())
    fine.chmod(0o644)
    dirs = (str(allowed),)
    assert "is outside the directories" in (files_problem(classifier_completion(outside), dirs) or "")
    assert "is a symbolic link or lies under one" in (files_problem(classifier_completion(link), dirs) or "")
    assert "not readable by the connector's uid 65532" in (
        files_problem(classifier_completion(private), dirs, reader_uid=65532) or "")
    assert files_problem(classifier_completion(private), dirs) is None  # an in-process connector: the agent's rights
    assert files_problem(classifier_completion(fine), dirs, reader_uid=65532) is None


def test_a_chmod_the_check_asked_for_is_seen_at_the_next_heartbeat(tmp_path: Path) -> None:
    path = tmp_path / "reach.onnx"
    path.write_bytes(SHIPPED_CLASSIFIER.read_bytes())
    path.chmod(0o600)
    check = CompletionFilesCheck(dirs=(str(tmp_path),), reader_uid=65532)
    assert "chmod o+r" in (check.problem(classifier_completion(path)) or "")
    path.chmod(0o644)  # changes neither content nor mtime: only the mode and ctime
    assert check.problem(classifier_completion(path)) is None
