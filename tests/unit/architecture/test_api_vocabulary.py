"""``armnet_core.api`` is the one definition of the API's vocabulary, in step with ``crds/``."""

from __future__ import annotations

import re

import pytest
from armnet_core import api
from armnet_core.models import JobStatus

from tests.unit.architecture.crds import CRDS, crd

pytestmark = pytest.mark.unit

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


PACKAGES = [CRDS.parent / p for p in ("runtime/src", "operator", "agent", "cli", "fms")]


def test_each_armnet_io_key_is_spelled_in_one_module_only() -> None:
    """A label, annotation or finalizer two processes share was spelled in each (and could drift apart):
    a key has one module that spells it; the others import its name (``armnet_core.api`` for keys on
    RobotJobs and Cells)."""
    spelled: dict[str, set[str]] = {}
    for root in PACKAGES:
        for path in root.rglob("*.py"):
            if "_pb2" in path.name:
                continue
            for key in re.findall(r"""["'](armnet\.io/[a-z][a-z0-9.-]*)["']""", path.read_text()):
                spelled.setdefault(key, set()).add(str(path.relative_to(CRDS.parent)))
    twice = {key: sorted(paths) for key, paths in spelled.items() if len(paths) > 1}
    assert twice == {}, f"keys spelled in more than one module: {twice}"
