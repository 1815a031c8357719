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
from tests.support.unattended import (
    CAMERAS,
    SCRIPTED_RESET,
    check_scored_reset_scored,
    target_completion,
)

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]

ROLLOUTS = 10


@pytest.fixture(scope="module")
def bed(k8s: Any, podman: Any, base_image: str) -> Iterator[AgentBed]:
    namespace = k8s.create_namespace("unattended")
    bed = AgentBed(k8s, podman, base_image, namespace)  # no NATS: no operator input can reach the cell
    bed.unattended = bed.add_cell(  # type: ignore[attr-defined]
        "unattended", completion=target_completion(), cameras=CAMERAS, reset=SCRIPTED_RESET)
    bed.start_operator()
    bed.start_agent()
    try:
        bed.wait_ready(bed.unattended, timeout=90)  # type: ignore[attr-defined]
        yield bed
    finally:
        bed.stop()
        k8s.delete_namespace(namespace)


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
    check_scored_reset_scored(st, ROLLOUTS)
    assert bed.wait(lambda: metric(bed, "armnet_agent_auto_resets_total", 'outcome="worked"') == ROLLOUTS, 15,
                    "the agent's metric of the scripted resets")

    def auto_reset_condition() -> dict[str, Any] | None:
        conditions = {c["type"]: c for c in (bed.cell(bed.unattended).get("status") or {}).get(  # type: ignore[attr-defined]
            "conditions", [])}
        condition = conditions.get("AutoResetWorking")
        return condition if condition is not None and condition.get("reason") == "Worked" else None

    assert bed.wait(auto_reset_condition, 15, "AutoResetWorking on the cell")["status"] == "True"
