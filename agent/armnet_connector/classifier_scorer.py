"""The ``classifier`` scorer: a learned success classifier (an ONNX model file) scores each frame.

The completion monitor calls :meth:`ClassifierScorer.score` on its own thread, off the
job's path. The model is the cell owner's (``completion.classifier.model``, a file on the
robot host) and runs in OpenCV's DNN module, which the connector already carries for its
cameras: no second inference runtime in the image, and a model of any framework that
exports ONNX. The contract a model meets (``classifier_input`` is the one definition the
training tool uses too):

- one input, ``1 x 3 x S x S`` float32: the frame resized to ``S x S`` (``inputSize``),
  RGB, scaled to 0..1;
- one output holding a single number, a logit: its sigmoid is the frame's score, a hit
  when it reaches ``threshold``.

A model file that is missing, not a regular file, over ``MAX_MODEL_BYTES``, not an ONNX
model OpenCV can run, or that answers anything but one finite number raises
:class:`ClassifierModelError` saying which, on every score (counted in
``completion_scorer_errors``: the frame is a miss). The size is checked before the file
is read, and the read itself stops one byte past the cap, so a file that grows meanwhile
cannot fill the connector's memory. The node agent runs the same check
(:func:`model_problem`) for the Cell's ``CompletionReady`` condition, so a cell with a bad
model is not bound in the first place.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np
from armnet_core.cell_completion import MAX_MODEL_BYTES, ClassifierConfig

from .host_files import HostFileError, read_host_file
from .scoring import FrameScore, frame_problem


class ClassifierModelError(RuntimeError):
    """The model cannot score: the message says what is wrong with the file and what to do."""


def classifier_input(frame: Any, size: int) -> Any:
    """A BGR ``height x width x 3`` uint8 frame as the model's input: ``1 x 3 x size x size`` float32 RGB 0..1."""
    import cv2

    square = cv2.resize(np.ascontiguousarray(frame), (size, size), interpolation=cv2.INTER_AREA)
    rgb = cv2.cvtColor(square, cv2.COLOR_BGR2RGB)
    return np.ascontiguousarray(rgb.transpose(2, 0, 1)[None], dtype=np.float32) / np.float32(255.0)


def read_model_bytes(path: str) -> bytes:
    """The model file's bytes, or ``ClassifierModelError``: missing, not a plain file, empty or over the cap."""
    try:
        data = read_host_file(path, MAX_MODEL_BYTES, "the model file")
    except HostFileError as exc:
        raise ClassifierModelError(f"{exc}; fix the file or spec.completion.classifier.model") from None
    if not data:
        raise ClassifierModelError(f"the model file {path} is empty")
    return data


def load_model(config: ClassifierConfig) -> Any:
    """The model as an OpenCV DNN network, checked to answer one finite number for a blank frame."""
    import cv2

    if config.model is None:
        raise ClassifierModelError(
            "completion.classifier.modelFrom names a ConfigMap, which only a node agent in the cluster reads "
            "(it writes the model to a file for the connector); give completion.classifier.model, a file, here")
    data = read_model_bytes(config.model)
    try:
        net = cv2.dnn.readNetFromONNX(np.frombuffer(data, dtype=np.uint8))
    except cv2.error as exc:
        raise ClassifierModelError(
            f"the model file {config.model} is not an ONNX model OpenCV can run ({_reason(exc)}); export the classifier "
            "to ONNX (docs/connector.md, \"Scoring by a learned classifier\")") from None
    net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
    net.setPreferableTarget(cv2.dnn.DNN_TARGET_CPU)
    blank = np.zeros((config.input_size, config.input_size, 3), np.uint8)
    _logit(net, classifier_input(blank, config.input_size), config)
    return net


def model_problem(config: ClassifierConfig) -> str | None:
    """Why the model cannot score (the file, its format, its answer), None when it can: the agent's check."""
    try:
        load_model(config)
    except ClassifierModelError as exc:
        return str(exc)
    return None


def _logit(net: Any, blob: Any, config: ClassifierConfig) -> float:
    import cv2

    try:
        net.setInput(blob)
        out = np.asarray(net.forward())
    except cv2.error as exc:
        raise ClassifierModelError(
            f"the model {config.model} failed on a {config.input_size}x{config.input_size} RGB input ({_reason(exc)}); "
            "check completion.classifier.inputSize against the size it was trained on") from None
    if out.size != 1:
        raise ClassifierModelError(
            f"the model {config.model} answers {out.size} numbers; a completion classifier answers one logit")
    value = float(out.reshape(-1)[0])
    if not math.isfinite(value):
        raise ClassifierModelError(f"the model {config.model} answered {value}; a logit must be a finite number")
    return value


def _reason(exc: BaseException) -> str:
    """The last line of an OpenCV error (its assertion), short."""
    lines = str(exc).strip().splitlines()
    return lines[-1][:200] if lines else type(exc).__name__


def sigmoid(logit: float) -> float:
    """The logistic function, without overflow for large negative logits."""
    if logit >= 0:
        return 1.0 / (1.0 + math.exp(-logit))
    z = math.exp(logit)
    return z / (1.0 + z)


class ClassifierScorer:
    """Scores a frame with the cell's classifier; the model is loaded on the first score (the monitor's thread).

    Why not at construction: the connector builds its monitor while it starts, and a
    bad model file must cost the cell its completion verdicts (and say why), never
    the connector's start. A model that failed to load is not read again for this
    connector (one per job): every score raises the same error. Scores come from the
    monitor's one thread; the lock guards the load only (an OpenCV ``Net`` is not for
    two threads at once).
    """

    def __init__(self, config: ClassifierConfig) -> None:
        self.config = config
        self._net: Any = None
        self._error: str | None = None
        self._lock = threading.Lock()

    def score(self, frame: Any) -> FrameScore:
        problem = frame_problem(frame)
        if problem is not None:
            return FrameScore(False, 0.0, problem)
        net = self._loaded()
        value = sigmoid(_logit(net, classifier_input(frame, self.config.input_size), self.config))
        hit = value >= self.config.threshold
        return FrameScore(hit, value, f"the classifier scored {value:.2f} (threshold {self.config.threshold:g})")

    def _loaded(self) -> Any:
        with self._lock:
            if self._net is None and self._error is None:
                try:
                    self._net = load_model(self.config)
                except ClassifierModelError as exc:
                    self._error = str(exc)
            if self._error is not None:
                raise ClassifierModelError(self._error)
            return self._net


__all__ = [
    "ClassifierModelError",
    "ClassifierScorer",
    "classifier_input",
    "load_model",
    "model_problem",
    "read_model_bytes",
    "sigmoid",
]
