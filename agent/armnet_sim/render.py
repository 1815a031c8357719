"""Draw the simulated joint state as a camera picture (pure: state in, pixels out).

The picture is a schematic, not a photo: for each arm a side view of the
shoulder-lift / elbow / wrist chain with the gripper jaws, plus one gauge per
joint. It exists so a job's camera stream visibly changes when the arm moves
and stays identical while it is still.

It is also a task scene a completion monitor can score: each arm's panel shows
a blue target pad, and a red disc marks the arm's end effector (the gripper's
base, where the wrist link ends). The side view is a planar projection: the
base sits at the bottom middle of the panel's upper part, and shoulder_lift,
elbow_flex and wrist_flex turn links of 0.42, 0.38 and 0.2 of the scene's size
in the picture's plane (0 degrees: straight up; positive: towards the right);
shoulder_pan, wrist_roll and the gripper do not move the disc. The pad sits
where the disc is at ``TARGET_POSE``, so a job that drives the arm there puts
the disc on the pad; ``target_region`` gives the pad as fractions of the picture.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping

import cv2
import numpy as np
import numpy.typing as npt

JointAngles = Mapping[str, float]
Image = npt.NDArray[np.uint8]

_BACKGROUND = (32, 34, 40)
_LINK = (230, 160, 40)
_JOINT = (240, 240, 240)
_GAUGE = (60, 180, 110)
_TEXT = (200, 200, 200)
_CHAIN = ("shoulder_lift", "elbow_flex", "wrist_flex")
_LINK_LENGTHS = (0.42, 0.38, 0.2)
_SCENE_SHARE = 0.62  # of the panel's height; the gauges take the rest

#: The joint angles (degrees) that put the end effector on the target pad.
TARGET_POSE: Mapping[str, float] = {"shoulder_lift": 20.0, "elbow_flex": 40.0, "wrist_flex": 0.0}
#: Colours of the scene, RGB: a blue pad, and a red disc on the end effector.
TARGET_RGB = (40, 90, 230)
END_EFFECTOR_RGB = (230, 30, 30)
#: Half the pad's side and the disc's radius, as fractions of the scene's size.
_PAD_HALF = 0.06
_DISC_RADIUS = 0.03


def render_arms(arms: Mapping[str, JointAngles], width: int, height: int) -> Image:
    """An RGB ``height x width x 3`` uint8 picture of every arm's joints (degrees).

    Why the background is copied and one arm drawn in place: this runs for every
    frame of a moving arm (30 fps per camera) in the process that serves the cell,
    which a real camera's frames do not cost; filling the picture colour by colour
    and pasting a full-width panel back took ~2 ms of the ~2.7 ms of a frame.
    """
    image = _background(height, width).copy()
    if not arms:
        _text(image, "no arm attached", (8, height // 2), height)
        return image
    panel_w = width / len(arms)
    for index, (name, joints) in enumerate(arms.items()):
        x0 = int(index * panel_w)
        x1 = int((index + 1) * panel_w)
        region = image[:, x0:x1]
        # OpenCV draws only into contiguous arrays: a panel narrower than the picture is
        # drawn on a copy and pasted back; one arm's panel is the picture itself.
        panel = region if region.flags.c_contiguous else np.ascontiguousarray(region)
        _draw_arm(panel, name, joints)
        if panel is not region:
            region[:] = panel
    return image


@functools.lru_cache(maxsize=8)
def _background(height: int, width: int) -> Image:
    """The empty picture of one size, made once (read-only: callers copy it)."""
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[:] = _BACKGROUND
    image.flags.writeable = False
    return image


def chain_points(joints: JointAngles, w: int, h: int) -> list[tuple[float, float]]:
    """The base, elbow, wrist and end effector, in pixels of a ``w x h`` panel (the planar projection)."""
    scene_h = int(h * _SCENE_SHARE)
    scale = min(w, scene_h) * 0.9
    point = (w * 0.5, scene_h * 0.92)
    points = [point]
    angle = math.pi / 2  # straight up at every joint's mid-range
    for joint, length in zip(_CHAIN, _LINK_LENGTHS, strict=True):
        angle -= math.radians(joints.get(joint, 0.0))
        point = (point[0] + math.cos(angle) * length * scale, point[1] - math.sin(angle) * length * scale)
        points.append(point)
    return points


def target_region(width: int, height: int, arms: int = 1) -> tuple[float, float, float, float]:
    """The first arm's target pad as (x, y, width, height) fractions of a ``width x height`` picture.

    A completion region for the simulated camera is this rectangle (a cell file
    or a Cell spec copies the numbers; docs/simulator.md lists them for 640x480).
    """
    panel_w = int(width / arms)
    x0, y0, x1, y1 = _pad_corners(panel_w, height)
    return x0 / width, y0 / height, (x1 - x0) / width, (y1 - y0) / height


def _pad_corners(w: int, h: int) -> tuple[int, int, int, int]:
    cx, cy = chain_points(TARGET_POSE, w, h)[-1]
    half = _scene_scale(w, h) * _PAD_HALF
    return int(round(cx - half)), int(round(cy - half)), int(round(cx + half)), int(round(cy + half))


def _scene_scale(w: int, h: int) -> float:
    return min(w, int(h * _SCENE_SHARE)) * 0.9


def _draw_arm(panel: Image, name: str, joints: JointAngles) -> None:
    h, w = panel.shape[:2]
    scene_h = int(h * _SCENE_SHARE)
    x0, y0, x1, y1 = _pad_corners(w, h)
    cv2.rectangle(panel, (x0, y0), (x1 - 1, y1 - 1), TARGET_RGB, -1)
    _draw_chain(panel, joints, w, h)
    tip = chain_points(joints, w, h)[-1]
    cv2.circle(panel, _pt(tip), max(2, int(_scene_scale(w, h) * _DISC_RADIUS)), END_EFFECTOR_RGB, -1)
    _draw_gauges(panel, joints, top=scene_h, w=w, h=h)
    _text(panel, name, (6, max(12, h // 24)), h)


def _draw_chain(panel: Image, joints: JointAngles, w: int, h: int) -> None:
    scene_h = int(h * _SCENE_SHARE)
    scale = _scene_scale(w, h)
    points = chain_points(joints, w, h)
    base = points[0]
    cv2.line(panel, _pt((base[0] - w * 0.2, base[1])), _pt((base[0] + w * 0.2, base[1])), _JOINT, 2)
    # shoulder_pan has no side-view component: show it as the base's tilt marker.
    pan = math.radians(joints.get("shoulder_pan", 0.0))
    marker = (base[0] + math.sin(pan) * w * 0.15, base[1] - math.cos(pan) * scene_h * 0.05)
    cv2.line(panel, _pt(base), _pt(marker), _GAUGE, 2)
    for start, end in zip(points, points[1:], strict=False):
        cv2.line(panel, _pt(start), _pt(end), _LINK, max(2, int(scale / 60)))
        cv2.circle(panel, _pt(start), max(3, int(scale / 80)), _JOINT, -1)
    angle = math.pi / 2 - sum(math.radians(joints.get(joint, 0.0)) for joint in _CHAIN)
    _draw_gripper(panel, points[-1], angle, joints, scale)


def _draw_gripper(
    panel: Image, tip: tuple[float, float], angle: float, joints: JointAngles, scale: float
) -> None:
    # The gripper reads 0..100 % closed..open in LeRobot terms; in degrees its range is
    # about +-60, so map it to an opening of 5..45 degrees per jaw.
    opening = math.radians(25 + max(-20.0, min(20.0, joints.get("gripper", 0.0) / 3)))
    roll = math.radians(joints.get("wrist_roll", 0.0))
    jaw = scale * 0.09
    for side in (-1, 1):
        a = angle + side * opening * (0.6 + 0.4 * math.cos(roll))
        end = (tip[0] + math.cos(a) * jaw, tip[1] - math.sin(a) * jaw)
        cv2.line(panel, _pt(tip), _pt(end), _JOINT, 2)


def _draw_gauges(panel: Image, joints: JointAngles, *, top: int, w: int, h: int) -> None:
    names = list(joints)
    if not names:
        return
    row_h = (h - top) / len(names)
    for row, name in enumerate(names):
        y0 = top + row * row_h
        y_mid = int(y0 + row_h / 2)
        x_left, x_right = int(w * 0.38), int(w * 0.96)
        cv2.rectangle(panel, (x_left, int(y0 + 2)), (x_right, int(y0 + row_h - 2)), _TEXT, 1)
        centre = (x_left + x_right) // 2
        value = max(-180.0, min(180.0, float(joints[name])))
        end = int(centre + value / 180.0 * (x_right - x_left) / 2)
        cv2.rectangle(
            panel,
            (min(centre, end), int(y0 + 4)),
            (max(centre, end), int(y0 + row_h - 4)),
            _GAUGE,
            -1,
        )
        _text(panel, name[:13], (4, y_mid + 4), h)


def _text(image: Image, text: str, origin: tuple[int, int], h: int) -> None:
    size = max(0.3, h / 1200)
    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, size, _TEXT, 1, cv2.LINE_AA)


def _pt(p: tuple[float, float]) -> tuple[int, int]:
    return int(round(p[0])), int(round(p[1]))
