"""A cell's ``completion`` settings: which camera the monitor watches and how it scores (pydantic, pure);
and its ``reset`` settings, whose scripted resets that monitor judges.

The Cell spec (``spec.completion``) as the operator and the node agent read it, a
local run's cell file and the connector's config all load this one model (plain
data: it imports no OpenCV, so the pure modules that read it stay free of it), so a
setting is checked the same way wherever it comes from. Every refusal says what to change: a cell owner's typo (an empty
region, a rate of 10 000 Hz, zero frames) must be an error on the cell, never a
monitor that silently scores nothing or burns the connector's CPU.
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic.alias_generators import to_camel

#: The ArUco dictionaries a cell may name (OpenCV's predefined ones, by their OpenCV name).
ARUCO_DICTIONARIES = ("DICT_4X4_50", "DICT_4X4_100", "DICT_5X5_50", "DICT_5X5_100", "DICT_6X6_50", "DICT_6X6_250")


def aruco_dictionary_size(name: str) -> int:
    """How many ids ``name`` (one of ``ARUCO_DICTIONARIES``) holds: the number after the last underscore."""
    return int(name.rsplit("_", 1)[1])


#: The fastest a monitor may score: a camera's usual rate; more only costs CPU beside the job.
MAX_RATE_HZ = 30.0
#: The slowest: ``block=True`` waits a few periods, which must stay well under a call's timeout.
MIN_RATE_HZ = 0.5
MAX_CONSECUTIVE_FRAMES = 300
#: Scorers this connector has.
SCORERS = ("region", "service", "classifier")
#: The longest a ``service`` scorer may take to answer: the monitor counts a score slower than
#: its limit (``SLOW_SCORE_S`` in the connector, 1 s) as "not complete" anyway.
MAX_SERVICE_TIMEOUT_S = 1.0
MIN_SERVICE_TIMEOUT_S = 0.05
#: The largest model file a ``classifier`` scorer loads: a success classifier for one task is a
#: few kB to a few MB; a larger file is refused before it is read (a 2 GB file must not fill
#: the connector's memory).
MAX_MODEL_BYTES = 64 << 20
#: The side of the square picture a classifier sees, in pixels (the frame is resized to it).
MIN_INPUT_SIZE = 16
MAX_INPUT_SIZE = 512


class _Model(BaseModel):
    model_config = ConfigDict(alias_generator=to_camel, populate_by_name=True, extra="forbid", frozen=True)


def _bounded(value: Any, name: str, low: float, high: float, kinds: tuple[type[int] | type[float], ...],
             span: str) -> Any:
    """``value`` if finite and, when a number of ``kinds``, within ``low``..``high``; else why, with ``span``."""
    _finite(value, name)
    if isinstance(value, kinds) and not low <= value <= high:
        raise ValueError(f"{name} is {value}; give {span}")
    return value


def _one_of(value: str, name: str, known: Any, what: str) -> str:
    """``value`` if it is one of ``known``; else why, listing them."""
    if value not in known:
        raise ValueError(f"{name} {value[:40]!r} {what}; use one of {list(known)}")
    return value


def _finite(value: Any, what: str) -> Any:
    if isinstance(value, bool):
        raise ValueError(f"{what} must be a number, got {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{what} is {value}; give a finite number")
    return value


class RegionConfig(_Model):
    """The target region, as fractions of the picture: its top-left corner (left, top), then its size.

    Why not x and y: Kubernetes reads YAML 1.1, where a bare ``y`` key is the boolean true.
    """

    left: float
    top: float
    width: float
    height: float

    @field_validator("left", "top", "width", "height", mode="before")
    @classmethod
    def _numbers(cls, value: Any) -> Any:
        return _finite(value, "completion.region fields")

    @model_validator(mode="after")
    def _inside_the_picture(self) -> RegionConfig:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(
                f"completion.region is empty ({self.width} x {self.height}); give width and height above 0 "
                "as fractions of the picture (e.g. width: 0.2)"
            )
        if self.left < 0 or self.top < 0 or self.left + self.width > 1 or self.top + self.height > 1:
            raise ValueError(
                f"completion.region (left {self.left}, top {self.top}, width {self.width}, height {self.height}) "
                "leaves the picture; left, top, left + width and top + height must lie between 0 and 1 "
                "(fractions of the picture, origin top-left)"
            )
        return self


class ColourConfig(_Model):
    """An OpenCV HSV range: hue 0..179 (hueMin > hueMax wraps through red), saturation and value 0..255."""

    hue_min: int = Field(ge=0, le=179)
    hue_max: int = Field(ge=0, le=179)
    saturation_min: int = Field(default=80, ge=0, le=255)
    saturation_max: int = Field(default=255, ge=0, le=255)
    value_min: int = Field(default=80, ge=0, le=255)
    value_max: int = Field(default=255, ge=0, le=255)

    @model_validator(mode="after")
    def _ordered(self) -> ColourConfig:
        if self.saturation_min > self.saturation_max or self.value_min > self.value_max:
            raise ValueError(
                "completion.colour: saturationMin/valueMin must not exceed saturationMax/valueMax "
                "(only the hue may wrap, with hueMin > hueMax)"
            )
        return self


def _host_file(value: str, name: str, example: str) -> str:
    """``value`` if it is a normalized absolute path (a file on the robot host), else why, with ``example``."""
    if not value.startswith("/") or "\x00" in value:
        raise ValueError(f"{name} {value[:80]!r}: give the absolute path of a file on the robot host (e.g. {example})")
    if "/../" in f"{value}/" or "/./" in f"{value}/" or "//" in value:
        raise ValueError(f"{name} {value[:80]!r}: give a normalized absolute path (no '..', '.' or '//' parts)")
    return value


class ServiceConfig(_Model):
    """An external scorer: the monitor POSTs each frame it scores (JPEG) and reads ``{"score": 0..1}`` back.

    The URL is the cell owner's (in the Cell, never a job's); a service that is slow
    (past ``timeoutSeconds``), down or answers anything else counts as "not complete"
    and is reported, never waited for beyond the timeout. A judge that wants
    credentials gets a bearer token read from ``tokenFile``, a file on the robot host
    (never in the Cell or a pod's spec, where tenants could read it).
    """

    url: str = Field(min_length=8, max_length=2048, pattern=r"^https?://[^\s]+$",
                     description="http(s) endpoint that scores one JPEG frame")
    timeout_seconds: float = Field(default=0.5, description="how long one score may take")
    threshold: float = Field(default=0.5, ge=0, le=1, description="a frame scored at least this is a hit")
    token_file: str | None = Field(default=None, min_length=2, max_length=1024,
                                   description="file on the robot host holding the bearer token the judge wants")

    @field_validator("token_file")
    @classmethod
    def _token_file(cls, value: str | None) -> str | None:
        if value is None:
            return None
        return _host_file(value, "completion.service.tokenFile", "/var/lib/armnet/secrets/judge-token")

    @field_validator("timeout_seconds", mode="before")
    @classmethod
    def _timeout(cls, value: Any) -> Any:
        return _bounded(value, "completion.service.timeoutSeconds", MIN_SERVICE_TIMEOUT_S, MAX_SERVICE_TIMEOUT_S,
                        (int, float), f"{MIN_SERVICE_TIMEOUT_S:g} to {MAX_SERVICE_TIMEOUT_S:g} seconds "
                        "(a slower score counts as not complete)")

    @field_validator("threshold", mode="before")
    @classmethod
    def _threshold(cls, value: Any) -> Any:
        return _finite(value, "completion.service.threshold")


#: A ConfigMap's name (a DNS subdomain) and one of its keys, as Kubernetes spells them.
_CONFIGMAP_NAME = r"^[a-z0-9]([-a-z0-9.]*[a-z0-9])?$"
_CONFIGMAP_KEY = r"^[-._a-zA-Z0-9]+[.]onnx$"


class ConfigMapKeyRef(_Model):
    """One key of a ConfigMap in the node agent's own namespace (the platform's, never a tenant's)."""

    name: str = Field(min_length=1, max_length=253, pattern=_CONFIGMAP_NAME, description="the ConfigMap's name")
    key: str = Field(min_length=6, max_length=253, pattern=_CONFIGMAP_KEY,
                     description="the key holding the model (binaryData, ending in .onnx)")


class ModelSource(_Model):
    """Where a classifier's model comes from when it is not a file on the robot host."""

    config_map_key_ref: ConfigMapKeyRef


class ClassifierConfig(_Model):
    """A learned success classifier: an ONNX model, run by OpenCV's DNN module.

    The contract (docs/connector.md, "Scoring by a learned classifier"): one input of
    ``1 x 3 x inputSize x inputSize`` float32, the frame resized to that square, RGB,
    scaled to 0..1; one output, a single logit, whose sigmoid is the score. The model is
    the cell owner's (in the Cell, never a job's): a file on the robot host (``model``),
    or a key of a ConfigMap in the node agent's namespace (``modelFrom``), which the agent
    writes to a file of its own (``with_model_file``) before anything reads it. It is
    checked where the cell's connector runs (``CompletionReady`` on the Cell says why it
    cannot be used).
    """

    model: str | None = Field(default=None, min_length=2, max_length=1024,
                              description="absolute path of the .onnx model file on the robot host")
    model_from: ModelSource | None = Field(default=None, description="the model from a ConfigMap of the platform's")
    threshold: float = Field(default=0.5, ge=0, le=1, description="a frame scored at least this is a hit")
    input_size: int = Field(default=64, description="side of the square picture the model sees, in pixels")

    @field_validator("threshold", mode="before")
    @classmethod
    def _threshold(cls, value: Any) -> Any:
        return _finite(value, "completion.classifier.threshold")

    @field_validator("input_size", mode="before")
    @classmethod
    def _input_size(cls, value: Any) -> Any:
        return _bounded(value, "completion.classifier.inputSize", MIN_INPUT_SIZE, MAX_INPUT_SIZE, (int,),
                        f"{MIN_INPUT_SIZE} to {MAX_INPUT_SIZE} pixels (the side the model was trained on)")

    @model_validator(mode="after")
    def _one_model(self) -> ClassifierConfig:
        if (self.model is None) == (self.model_from is None):
            raise ValueError("completion.classifier needs exactly one model: model (a file on the robot host) or "
                             "modelFrom.configMapKeyRef (a ConfigMap in the node agent's namespace)")
        return self

    def with_model_file(self, path: str) -> ClassifierConfig:
        """This classifier reading its model from the file ``path`` (where the agent wrote ``modelFrom``'s)."""
        return self.model_copy(update={"model": self._normal_path(path), "model_from": None})

    @field_validator("model")
    @classmethod
    def _normal_path(cls, value: str | None) -> str | None:
        if value is None:
            return None
        if not value.endswith(".onnx"):
            raise ValueError(f"completion.classifier.model {value[:80]!r}: give the absolute path of an ONNX "
                             "model file on the robot host, ending in .onnx (e.g. /var/lib/armnet/models/reach.onnx)")
        return _host_file(value, "completion.classifier.model", "/var/lib/armnet/models/reach.onnx")


class CompletionConfig(_Model):
    """How the cell's completion monitor scores an episode (docs/connector.md, "Completion monitor")."""

    camera: str = Field(min_length=1, max_length=253, description="the cell camera the monitor watches")
    scorer: str = "region"
    region: RegionConfig | None = Field(default=None, description="region scorer: where the object must be")
    service: ServiceConfig | None = Field(default=None, description="service scorer: the endpoint that scores")
    classifier: ClassifierConfig | None = Field(default=None, description="classifier scorer: the model that scores")
    colour: ColourConfig | None = Field(default=None, description="the object is a blob of this HSV range")
    aruco_id: int | None = Field(default=None, description="the object is the ArUco marker of this id")
    aruco_dictionary: str = "DICT_4X4_50"
    min_pixels: int = Field(default=30, description="the smallest blob of the colour that counts as the object")
    consecutive_frames: int = Field(default=3, description="hits in a row before the episode is complete")
    rate_hz: float = Field(default=5.0, description="frames scored per second")

    @field_validator("scorer")
    @classmethod
    def _known_scorer(cls, value: str) -> str:
        return _one_of(value, "completion.scorer", SCORERS, "is not available")

    @field_validator("rate_hz", mode="before")
    @classmethod
    def _rate(cls, value: Any) -> Any:
        return _bounded(value, "completion.rateHz", MIN_RATE_HZ, MAX_RATE_HZ, (int, float),
                        f"{MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} frames per second "
                        "(the monitor shares the connector's CPU with the job)")

    @field_validator("consecutive_frames", mode="before")
    @classmethod
    def _frames(cls, value: Any) -> Any:
        return _bounded(value, "completion.consecutiveFrames", 1, MAX_CONSECUTIVE_FRAMES, (int,),
                        f"1 to {MAX_CONSECUTIVE_FRAMES} "
                        "(how many scored frames in a row must show the object in the region)")

    @field_validator("min_pixels", mode="before")
    @classmethod
    def _pixels(cls, value: Any) -> Any:
        return _bounded(value, "completion.minPixels", 1, 10_000_000, (int,), "1 to 10000000 pixels")

    @field_validator("aruco_dictionary")
    @classmethod
    def _dictionary(cls, value: str) -> str:
        return _one_of(value, "completion.arucoDictionary", ARUCO_DICTIONARIES, "is unknown")

    @model_validator(mode="after")
    def _one_object(self) -> CompletionConfig:
        own = {"service": self.service, "classifier": self.classifier}
        for scorer, setting in own.items():
            if setting is not None and self.scorer != scorer:
                raise ValueError(f"completion.{scorer} is for scorer {scorer}; this completion's scorer is {self.scorer}")
        if self.scorer in own:
            if own[self.scorer] is None:
                needs = "its url" if self.scorer == "service" else "its model file"
                raise ValueError(f"completion.scorer {self.scorer} needs completion.{self.scorer} ({needs})")
            if self.region is not None or self.colour is not None or self.aruco_id is not None:
                alone = "its endpoint" if self.scorer == "service" else "its model"
                raise ValueError(
                    f"completion.scorer {self.scorer} scores with {alone} alone: leave out region, colour and arucoId"
                )
            return self
        if self.region is None:
            raise ValueError("completion.scorer region needs completion.region (where the object must be)")
        if (self.colour is None) == (self.aruco_id is None):
            raise ValueError(
                "completion needs exactly one object to look for: a colour (an HSV range) or an arucoId"
            )
        size = aruco_dictionary_size(self.aruco_dictionary)
        if self.aruco_id is not None and not 0 <= self.aruco_id < size:
            raise ValueError(
                f"completion.arucoId is {self.aruco_id}; {self.aruco_dictionary} holds ids 0 to {size - 1}"
            )
        return self


def host_files(completion: CompletionConfig | None) -> tuple[str, ...]:
    """The robot host's files the completion monitor reads (a classifier's model, a judge's token file).

    A job pod's connector gets each mounted read-only at the same path; the node agent
    checks them for the Cell's ``CompletionReady``.
    """
    if completion is None:
        return ()
    if completion.classifier is not None:
        # A model from a ConfigMap is no host file until the node agent wrote it (``with_model_file``).
        return () if completion.classifier.model is None else (completion.classifier.model,)
    if completion.service is not None and completion.service.token_file is not None:
        return (completion.service.token_file,)
    return ()


#: Where a node agent lets a completion monitor read files unless told otherwise
#: (``--completion-files-dir``; the Helm chart mounts both at the same path).
DEFAULT_COMPLETION_DIRS = ("/var/lib/armnet/models", "/var/lib/armnet/secrets")


def outside_dirs(paths: Any, dirs: Any) -> str | None:
    """Why one of ``paths`` is not inside one of ``dirs`` (the agent's allowed directories), None if all are.

    Why a fence at all: a Cell names files the connector reads with the agent's
    rights and sends (a token) to the Cell's URL; without it, whoever may edit a
    Cell could read any single-line file of the host, the agent's own credentials
    included. Paths are compared as given: the models already refuse ``..``, ``.``
    and ``//`` parts, and the file checks refuse a symbolic link.
    """
    allowed = [d.rstrip("/") for d in dirs if d]
    for path in paths:
        if not any(path.startswith(f"{d}/") for d in allowed):
            return (f"{path[:200]} is outside the directories this node agent reads completion files from "
                    f"({', '.join(allowed) or 'none'}); put the file there (the agent's --completion-files-dir)")
    return None


def unknown_camera(completion: CompletionConfig | None, cameras: Any) -> str | None:
    """Why ``completion`` names no camera of the cell (``cameras``: its names), None if it does."""
    if completion is None or completion.camera in cameras:
        return None
    return (
        f"completion.camera {completion.camera[:64]!r} is not a camera of this cell; "
        f"name one of {sorted(cameras)} (spec.cameras)"
    )



# -- resets without a person (``spec.reset``) ---------------------------------------------------

#: How a cell's workspace is put back between episodes when a job calls ``ctx.cell.reset()``.
RESET_MODES = ("Operator", "Scripted")
MAX_RESET_POSES = 16
MAX_RESET_ATTEMPTS = 10
MAX_SETTLE_SECONDS = 30.0
#: The SO-101's joints, as its calibration file and LeRobot name them. The gripper is in
#: LeRobot's ``range_0_100`` (0 closed .. 100 open), every other joint in degrees.
SO101_JOINTS = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
SO101_GRIPPER = "gripper"
#: Where a degrees joint can be at all (one turn of the servo, centred on its calibrated middle).
DEGREES_SPAN = (-180.0, 180.0)
GRIPPER_SPAN = (0.0, 100.0)


class ResetConfig(_Model):
    """How ``ctx.cell.reset()`` puts the workspace back (docs/connector.md, "Resets without a person").

    ``Operator``: a person confirms (the default). ``Scripted``: after the arm's rest move
    the connector drives it through ``poses`` itself, under the cell's safety limits, and
    the cell's completion monitor judges the scene; after ``attempts`` failed tries a
    person confirms, as with ``Operator``.
    """

    mode: str = "Operator"
    poses: tuple[dict[str, float], ...] = Field(
        default=(), description="joint -> value (degrees; the gripper 0..100), visited in order"
    )
    attempts: int = Field(default=3, description="scripted tries before a person is asked")
    settle_seconds: float = Field(default=1.0, description="wait after the last pose before the scene is judged")

    @field_validator("mode")
    @classmethod
    def _known_mode(cls, value: str) -> str:
        return _one_of(value, "reset.mode", RESET_MODES, "is not a reset mode")

    @field_validator("attempts", mode="before")
    @classmethod
    def _attempts(cls, value: Any) -> Any:
        return _bounded(value, "reset.attempts", 1, MAX_RESET_ATTEMPTS, (int,),
                        f"1 to {MAX_RESET_ATTEMPTS} (scripted tries before a person is asked)")

    @field_validator("settle_seconds", mode="before")
    @classmethod
    def _settle(cls, value: Any) -> Any:
        return _bounded(value, "reset.settleSeconds", 0, MAX_SETTLE_SECONDS, (int, float),
                        f"0 to {MAX_SETTLE_SECONDS:g} seconds")

    @field_validator("poses", mode="before")
    @classmethod
    def _poses(cls, value: Any) -> Any:
        if not isinstance(value, list | tuple):
            return value
        if len(value) > MAX_RESET_POSES:
            raise ValueError(f"reset.poses has {len(value)} poses; give at most {MAX_RESET_POSES}")
        for number, pose in enumerate(value, 1):
            if not isinstance(pose, dict) or not pose:
                raise ValueError(f"reset.poses[{number - 1}] must be a non-empty mapping joint -> value, e.g. "
                                 "{shoulder_lift: -30, elbow_flex: 60}")
            for joint, angle in pose.items():
                if isinstance(angle, bool) or not isinstance(angle, int | float):
                    raise ValueError(f"reset.poses[{number - 1}].{str(joint)[:40]} must be a number, got {angle!r}"[:300])
                _finite(angle, f"reset.poses[{number - 1}].{str(joint)[:40]}")
        return value

    @model_validator(mode="after")
    def _poses_for_scripted(self) -> ResetConfig:
        if self.mode == "Scripted" and not self.poses:
            raise ValueError("reset.mode Scripted needs reset.poses (1 to 16 poses the connector drives the arm through)")
        if self.mode == "Operator" and self.poses:
            raise ValueError("reset.poses are driven only with reset.mode Scripted; set mode: Scripted, or drop poses")
        return self

    @property
    def scripted(self) -> bool:
        return self.mode == "Scripted"


def reset_joints(arm_names: Any) -> dict[str, tuple[str, str]]:
    """Every pose key a cell with ``arm_names`` takes -> (arm, joint).

    A single-arm cell names the joint (``elbow_flex``); a cell of several arms prefixes it
    with the arm, as LeRobot's bimanual robots name their features (``left_elbow_flex``).
    """
    names = list(arm_names)
    if len(names) == 1:
        return {joint: (names[0], joint) for joint in SO101_JOINTS}
    return {f"{arm}_{joint}": (arm, joint) for arm in names for joint in SO101_JOINTS}


def split_pose(pose: Any, arm_names: Any) -> dict[str, dict[str, float]]:
    """One pose of ``reset.poses`` as arm -> {joint: value}; raises ``ValueError`` for an unknown key."""
    keys = reset_joints(arm_names)
    split: dict[str, dict[str, float]] = {}
    for key, value in pose.items():
        if key not in keys:
            raise ValueError(f"{str(key)[:64]!r} is not a joint of this cell; use {sorted(keys)}")
        arm, joint = keys[key]
        split.setdefault(arm, {})[joint] = float(value)
    return split


def reset_problem(reset: ResetConfig | None, completion: CompletionConfig | None, arm_names: Any) -> str | None:
    """Why ``reset`` cannot work on a cell with ``completion`` and ``arm_names``, None if it can.

    Checked wherever a Cell is read to run jobs (the node agent, the connector, a local
    cell file) and by the CRD's rules; the calibrated range of each joint is the
    connector's check, where the cell's calibration file is.
    """
    if reset is None or not reset.scripted:
        return None
    names = list(arm_names)
    if completion is None:
        return (
            "reset.mode Scripted needs the cell's completion monitor (spec.completion): it judges whether "
            "the scene is back at its start; add spec.completion, or use reset.mode Operator"
        )
    for number, pose in enumerate(reset.poses):
        try:
            split = split_pose(pose, names)
        except ValueError as exc:
            return f"reset.poses[{number}]: {exc}"
        for arm, joints in split.items():
            for joint, value in joints.items():
                low, high = GRIPPER_SPAN if joint == SO101_GRIPPER else DEGREES_SPAN
                if not low <= value <= high:
                    unit = "0 (closed) to 100 (open)" if joint == SO101_GRIPPER else "-180 to 180 degrees"
                    where = joint if len(names) == 1 else f"{arm}_{joint}"
                    return f"reset.poses[{number}].{where} is {value:g}; give {unit}"
    return None
