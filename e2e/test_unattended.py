"""An evaluation with nobody at the cell, end to end: scored, reset, scored, ten times.

Real kube-apiserver + etcd, the real ``armnet operator`` and ``armnet agent``, a Podman
container, the cell simulator driven by LeRobot's own Feetech bus through the connector.
The Cell has a completion monitor (the simulator's end-effector disc on its target pad)
and a scripted reset (``spec.reset.mode: Scripted``): the job's ``ctx.cell.reset()`` is
answered by the connector driving the arm to a pose away from the target and the monitor
judging the scene back at its start. The bed has no NATS: no operator input can reach
the cell at all, and the test sends none.
"""

from __future__ import annotations

import urllib.request
from collections.abc import Iterator
from typing import Any

import pytest

from e2e.agent_bed import EXAMPLES, JOBS, AgentBed
from e2e.scenarios import explain, status

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]

ROLLOUTS = 10
TARGET = {"shoulder_lift": 20.0, "elbow_flex": 40.0, "wrist_flex": 0.0}  # armnet_sim.render.TARGET_POSE
SHORT = {**TARGET, "elbow_flex": 25.0}  # e2e/jobs/unattended_eval.py's even rollouts
AWAY = {"shoulder_lift": -25.0, "elbow_flex": 10.0, "wrist_flex": 15.0}  # the cell's reset pose
NEAR = 3.0  # degrees: where the simulated arm settles around a goal


def target_completion() -> dict[str, Any]:
    """The cell's monitor looks for the simulator's end-effector disc on its target pad."""
    from armnet_sim.render import target_region

    left, top, width, height = target_region(640, 480)
    return {"camera": "front", "region": {"left": left, "top": top, "width": width, "height": height},
            "colour": {"hueMin": 170, "hueMax": 8, "saturationMin": 120, "valueMin": 80},
            "consecutiveFrames": 3, "rateHz": 15}


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str) -> Iterator[AgentBed]:
    namespace = k8s.create_namespace("unattended")
    bed = AgentBed(k8s, podman, base_image, namespace)  # no NATS: no operator input can reach the cell
    bed.unattended = bed.add_cell(  # type: ignore[attr-defined]
        "unattended", completion=target_completion(),
        cameras={"front": {"indexOrPath": 0, "width": 640, "height": 480, "fps": 30}},
        reset={"mode": "Scripted", "poses": [AWAY], "attempts": 2, "settleSeconds": 0.5})
    bed.start_operator()
    bed.start_agent()
    try:
        bed.wait_ready(bed.unattended, timeout=90)  # type: ignore[attr-defined]
        yield bed
    finally:
        bed.stop()
        k8s.delete_namespace(namespace)


def near(where: dict[str, float], goal: dict[str, float]) -> bool:
    return all(abs(where[joint] - angle) < NEAR for joint, angle in goal.items())


def metric(bed: AgentBed, name: str, labels: str) -> float:
    text = urllib.request.urlopen(f"http://127.0.0.1:{bed.metrics_port}/metrics", timeout=5).read().decode()
    for line in text.splitlines():
        if line.startswith(f"{name}{{{labels}}} "):
            return float(line.rsplit(" ", 1)[1])
    return 0.0


def test_an_evaluation_of_ten_rollouts_runs_scored_reset_scored_with_no_operator_input(bed: AgentBed) -> None:
    image = bed.image("unattended-eval", JOBS / "unattended_eval.py", (EXAMPLES / "_so101_moves.py",))
    bed.submit("unattended-eval", image, timeout=240, args={"rollouts": ROLLOUTS})

    st = status(bed.wait_phase("unattended-eval", timeout=240))

    assert st["phase"] == "succeeded", explain(st)
    seen = st["result"]["returnValue"]
    drove_onto_target = [index % 2 == 1 for index in range(1, ROLLOUTS + 1)]
    # What the arm really did: every reset left it at the cell's reset pose, every rollout ended where it drove.
    assert all(near(r["afterReset"], AWAY) for r in seen), seen
    assert all(near(r["ended"], TARGET if onto else SHORT) for r, onto in zip(seen, drove_onto_target, strict=True))
    # The monitor's answers to the job, and its verdicts on record, agree with that.
    assert [r["complete"] for r in seen] == drove_onto_target
    rollouts = st["rollouts"]
    assert [(r["index"], r["outcome"], r.get("markedBy")) for r in rollouts] == [
        (index, "success" if onto else "failure", "monitor")
        for index, onto in zip(range(1, ROLLOUTS + 1), drove_onto_target, strict=True)], rollouts
    assert [r["monitor"]["outcome"] for r in rollouts] == ["success" if onto else "failure"
                                                           for onto in drove_onto_target]
    # Every reset was the connector's, judged by the monitor; none asked a person.
    resets = st["result"]["safety"]["autoResets"]
    assert (resets.get("worked"), resets.get("fell_back"), resets["latest"]["outcome"]) == (ROLLOUTS, None, "worked")
    assert bed.wait(lambda: metric(bed, "armnet_agent_auto_resets_total", 'outcome="worked"') == ROLLOUTS, 15,
                    "the agent's metric of the scripted resets")

    def auto_reset_condition() -> dict[str, Any] | None:
        conditions = {c["type"]: c for c in (bed.cell(bed.unattended).get("status") or {}).get(  # type: ignore[attr-defined]
            "conditions", [])}
        condition = conditions.get("AutoResetWorking")
        return condition if condition is not None and condition.get("reason") == "Worked" else None

    assert bed.wait(auto_reset_condition, 15, "AutoResetWorking on the cell")["status"] == "True"
