"""``RobotJob.status.phase`` mirrors ``armnet_core.JobStatus``: one vocabulary for jobs everywhere."""

from __future__ import annotations

import pytest
from armnet_core import JobStatus, TerminalStatus
from armnet_operator.model import TERMINAL_PHASES, JobPhase

pytestmark = pytest.mark.unit


def test_every_job_phase_is_a_job_status_and_back() -> None:
    assert {phase.value for phase in JobPhase} == {status.value for status in JobStatus}


def test_the_operator_and_the_sdk_agree_on_what_is_terminal() -> None:
    assert {phase.value for phase in TERMINAL_PHASES} == {status.value for status in TerminalStatus}


def test_the_crd_offers_exactly_these_phases() -> None:
    from pathlib import Path

    import yaml

    crd = yaml.safe_load((Path(__file__).resolve().parents[3] / "crds" / "robotjob.yaml").read_text())
    schema = crd["spec"]["versions"][0]["schema"]["openAPIV3Schema"]
    phases = schema["properties"]["status"]["properties"]["phase"]["enum"]
    assert set(phases) == {status.value for status in JobStatus}
