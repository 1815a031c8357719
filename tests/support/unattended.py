"""The unattended evaluation's cell and what its job's status must show, for both launchers.

The job is e2e/jobs/unattended_eval.py: each rollout begins with ``ctx.cell.reset()`` (the
cell's scripted reset: the connector drives the arm to ``AWAY`` and the completion monitor
judges the scene back at its start), then drives the arm onto the simulator's target pad
(odd rollouts) or stops short of it (even ones), and asks the monitor. The container
launcher's run is e2e/test_unattended.py; the pod launcher's, the chart's real install
(tests/images/test_helm_install_node.py).
"""

from __future__ import annotations

from typing import Any

TARGET = {"shoulder_lift": 20.0, "elbow_flex": 40.0, "wrist_flex": 0.0}  # armnet_sim.render.TARGET_POSE
SHORT = {**TARGET, "elbow_flex": 25.0}  # e2e/jobs/unattended_eval.py's even rollouts
AWAY = {"shoulder_lift": -25.0, "elbow_flex": 10.0, "wrist_flex": 15.0}  # the cell's reset pose
NEAR = 3.0  # degrees: where the simulated arm settles around a goal
#: The cell's scripted reset (``spec.reset``).
SCRIPTED_RESET = {"mode": "Scripted", "poses": [AWAY], "attempts": 2, "settleSeconds": 0.5}
#: The cell's camera the monitor watches (``spec.cameras``).
CAMERAS = {"front": {"indexOrPath": 0, "width": 640, "height": 480, "fps": 30}}


def target_completion() -> dict[str, Any]:
    """The cell's monitor (``spec.completion``) looks for the simulator's end-effector disc on its target pad."""
    from armnet_sim.render import target_region

    left, top, width, height = target_region(640, 480)
    return {"camera": "front", "region": {"left": left, "top": top, "width": width, "height": height},
            "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80},
            "consecutiveFrames": 3, "rateHz": 15}


def near(where: dict[str, float], goal: dict[str, float]) -> bool:
    return all(abs(where[joint] - angle) < NEAR for joint, angle in goal.items())


def check_scored_reset_scored(status: dict[str, Any], rollouts: int) -> None:
    """The job's return value, ``status.rollouts`` and its safety record agree with what the arm really did.

    Every reset left the arm at the reset pose, every rollout ended where it drove; the monitor
    answered complete exactly for the rollouts onto the target, recorded each verdict as the
    rollout's outcome, and every reset was the connector's, judged by the monitor: none asked a person.
    """
    seen = status["result"]["returnValue"]
    onto_target = [index % 2 == 1 for index in range(1, rollouts + 1)]
    assert all(near(r["afterReset"], AWAY) for r in seen), seen
    assert all(near(r["ended"], TARGET if onto else SHORT) for r, onto in zip(seen, onto_target, strict=True)), seen
    assert [r["complete"] for r in seen] == onto_target, seen
    recorded = status["rollouts"]
    assert [(r["index"], r["outcome"], r.get("markedBy")) for r in recorded] == [
        (index, "success" if onto else "failure", "monitor")
        for index, onto in zip(range(1, rollouts + 1), onto_target, strict=True)], recorded
    assert [r["monitor"]["outcome"] for r in recorded] == ["success" if onto else "failure" for onto in onto_target]
    resets = status["result"]["safety"]["autoResets"]
    assert (resets.get("worked"), resets.get("fell_back"), resets["latest"]["outcome"]) == (rollouts, None, "worked")
