"""``armnet_core.api`` is the one definition of the API's vocabulary, in step with ``crds/``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_core import api
from armnet_core.models import JobStatus

pytestmark = pytest.mark.unit

CRDS = Path(__file__).resolve().parents[3] / "crds"


def crd(plural: str) -> dict[str, Any]:
    for path in CRDS.glob("*.yaml"):
        body: dict[str, Any] = yaml.safe_load(path.read_text())
        if body["spec"]["names"]["plural"] == plural:
            return body
    raise AssertionError(f"no CRD in crds/ serves {plural}")


@pytest.mark.parametrize("plural", [api.ROBOTJOBS, api.CELLS, api.CELLQUOTAS])
def test_every_crd_serves_the_group_and_version_the_packages_use(plural: str) -> None:
    body = crd(plural)

    assert body["spec"]["group"] == api.GROUP
    assert [v["name"] for v in body["spec"]["versions"] if v.get("served")] == [api.VERSION]
    assert api.API_VERSION == f"{api.GROUP}/{api.VERSION}"


def test_the_phases_are_the_robotjob_crds_phase_enum_in_its_order() -> None:
    version = crd(api.ROBOTJOBS)["spec"]["versions"][0]
    phase = version["schema"]["openAPIV3Schema"]["properties"]["status"]["properties"]["phase"]

    assert tuple(phase["enum"]) == api.PHASES == tuple(s.value for s in JobStatus)


def test_active_and_terminal_phases_are_disjoint_phases() -> None:
    assert api.ACTIVE_PHASES | api.TERMINAL_PHASES <= set(api.PHASES)
    assert not api.ACTIVE_PHASES & api.TERMINAL_PHASES
    assert api.TERMINAL_PHASES == {"succeeded", "failed", "timeout", "cancelled"}
