"""Labelled pictures of the simulated task scene, for training and measuring completion scorers.

Pure: a seed in, pictures out. Each sample is the simulated camera's picture of one
arm (``render.render_arms``, as BGR: what the completion monitor scores) in a pose
drawn around the task's target, labelled by geometry, not by any scorer: complete
when the end effector's disc has its centre on the target pad. The kinds of pose:

- ``success``: the disc's centre on the pad, at least ``SUCCESS_MARGIN_PX`` inside its edge;
- ``near_miss``: just off the pad, its centre ``NEAR_MISS_PX`` outside its edge
  (a pose a policy that almost made it ends in);
- ``far``: anywhere else the arm reaches;
- ``no_scene``: pictures that are no view of the task at all (the simulator's "no arm
  attached" picture, a flat colour, noise): a camera that shows something else must
  never be scored complete, and a learned classifier only learns that from examples.

A pose in the band between (a centre on the pad's very edge) is never drawn: its
label would be a matter of a pixel, which no camera decides. ``perturb`` changes the
lighting (gain and offset) and adds sensor noise, so a scorer is measured on
pictures it was not tuned on; the shipped classifier
(``data/reach_classifier.onnx``, ``bench/train_completion_classifier.py``) is trained on
one seed and measured on another (``bench/completion_accuracy.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .render import TARGET_POSE, chain_points, render_arms, target_region

#: The simulated camera's picture (the cell presets' camera size).
WIDTH, HEIGHT = 640, 480
SUCCESS_MARGIN_PX = 2.0
NEAR_MISS_PX = (4.0, 40.0)
KINDS = ("success", "near_miss", "far", "no_scene")
#: The shares of the kinds in ``samples`` (successes, near misses, far poses, no scene).
MIX = (0.38, 0.38, 0.18, 0.06)
#: The chain joints and their spread around the target (degrees) for a near pose.
CHAIN = ("shoulder_lift", "elbow_flex", "wrist_flex")
NEAR_SPREAD_DEG = 6.0
#: The classifier trained on these pictures, shipped for the simulated cells.
SHIPPED_CLASSIFIER = Path(__file__).parent / "data" / "reach_classifier.onnx"
#: The input side the shipped classifier was trained on (``completion.classifier.inputSize``).
SHIPPED_CLASSIFIER_INPUT = 96


@dataclass(frozen=True)
class SceneSample:
    image: Any  # BGR uint8, HEIGHT x WIDTH x 3
    complete: bool
    kind: str
    joints: dict[str, float]


def pad_distance(joints: dict[str, float], width: int = WIDTH, height: int = HEIGHT) -> float:
    """How far the disc's centre is outside the target pad, in pixels; negative: inside (by that much)."""
    x, y, w, h = target_region(width, height)
    left, top, right, bottom = x * width, y * height, (x + w) * width, (y + h) * height
    cx, cy = chain_points(joints, width, height)[-1]
    dx = max(left - cx, 0.0, cx - right)
    dy = max(top - cy, 0.0, cy - bottom)
    if dx == 0.0 and dy == 0.0:
        return -min(cx - left, right - cx, cy - top, bottom - cy)
    return math.hypot(dx, dy)


def kind_of(distance: float) -> str | None:
    """The kind a pose at ``distance`` (``pad_distance``) is, None in the ambiguous band."""
    if distance <= -SUCCESS_MARGIN_PX:
        return "success"
    if NEAR_MISS_PX[0] <= distance <= NEAR_MISS_PX[1]:
        return "near_miss"
    if distance > NEAR_MISS_PX[1]:
        return "far"
    return None


def _pose(rng: np.random.Generator, kind: str) -> dict[str, float]:
    """A random pose of ``kind``; the joints that do not move the disc vary too (the gauges change)."""
    others = {"shoulder_pan": rng.uniform(-60, 60), "wrist_roll": rng.uniform(-90, 90), "gripper": rng.uniform(0, 100)}
    for _ in range(10_000):
        if kind == "far":
            chain = {joint: float(rng.uniform(-80, 80)) for joint in CHAIN}
        else:
            spread = NEAR_SPREAD_DEG * (0.5 if kind == "success" else 1.5)
            chain = {joint: float(TARGET_POSE[joint] + rng.normal(0.0, spread)) for joint in CHAIN}
        if kind_of(pad_distance(chain)) == kind:
            return {**others, **chain}
    raise RuntimeError(f"no pose of kind {kind} found")  # pragma: no cover - the spreads make each kind common


def perturb(image: Any, rng: np.random.Generator, *, gain: tuple[float, float] = (0.6, 1.4),
            offset: tuple[float, float] = (-30.0, 30.0), noise: tuple[float, float] = (0.0, 8.0)) -> Any:
    """``image`` under another light (a gain and an offset) with Gaussian sensor noise."""
    g, o, sigma = rng.uniform(*gain), rng.uniform(*offset), rng.uniform(*noise)
    out = image.astype(np.float32) * g + o
    if sigma > 0:
        out += rng.normal(0.0, sigma, size=image.shape).astype(np.float32)
    return np.clip(out, 0, 255).astype(np.uint8)


def no_scene(rng: np.random.Generator) -> Any:
    """A BGR picture that shows no task: the simulator's "no arm attached", a flat colour, or noise."""
    choice = int(rng.integers(3))
    if choice == 0:
        return cv2.cvtColor(render_arms({}, WIDTH, HEIGHT), cv2.COLOR_RGB2BGR)
    if choice == 1:
        return np.full((HEIGHT, WIDTH, 3), rng.integers(0, 256, 3), dtype=np.uint8)
    return rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)


def sample(rng: np.random.Generator, kind: str, *, vary_light: bool = True) -> SceneSample:
    if kind == "no_scene":
        image = no_scene(rng)
        return SceneSample(perturb(image, rng) if vary_light else image, False, kind, {})
    joints = _pose(rng, kind)
    rgb = render_arms({"arm": joints}, WIDTH, HEIGHT)
    image = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    if vary_light:
        image = perturb(image, rng)
    return SceneSample(image, kind == "success", kind, joints)


def samples(seed: int, count: int, *, vary_light: bool = True) -> list[SceneSample]:
    """``count`` samples of the kinds in ``MIX``, reproducible from ``seed``."""
    rng = np.random.default_rng(seed)
    kinds = rng.choice(len(KINDS), size=count, p=MIX)
    return [sample(rng, KINDS[int(k)], vary_light=vary_light) for k in kinds]


def approach(steps: int, start: dict[str, float] | None = None) -> list[dict[str, float]]:
    """A straight move in joint space from ``start`` (default: arm raised) to the target pose, ``steps`` poses."""
    begin = start or {"shoulder_lift": -30.0, "elbow_flex": -20.0, "wrist_flex": 10.0}
    return [{joint: begin[joint] + (TARGET_POSE[joint] - begin[joint]) * i / (steps - 1) for joint in CHAIN}
            for i in range(steps)]


def frame_of(joints: dict[str, float]) -> Any:
    """The simulated camera's picture (BGR) of one arm in ``joints``, unperturbed."""
    return cv2.cvtColor(render_arms({"arm": joints}, WIDTH, HEIGHT), cv2.COLOR_RGB2BGR)


__all__ = [
    "HEIGHT",
    "KINDS",
    "SHIPPED_CLASSIFIER",
    "SHIPPED_CLASSIFIER_INPUT",
    "SceneSample",
    "WIDTH",
    "approach",
    "frame_of",
    "kind_of",
    "no_scene",
    "pad_distance",
    "perturb",
    "sample",
    "samples",
]
