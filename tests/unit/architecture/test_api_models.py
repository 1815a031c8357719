"""``armnet_core.resources`` models the RobotJob, Cell and CellQuota the CRDs in ``crds/`` define, field by field.

Every reader validates with these models; a field the CRD renames or drops, or one a
model invents, would be read as absent without an error. Each model field (by its
alias) must be a property of the CRD's schema at the same place, with the same
required fields and the same bounds where the model has one.
"""

from __future__ import annotations

from typing import Any

import pytest
from armnet_core import api, resources
from pydantic import BaseModel

from tests.unit.architecture.crds import crd

pytestmark = pytest.mark.unit

def schema(plural: str) -> dict[str, Any]:
    version = next(v for v in crd(plural)["spec"]["versions"] if v["name"] == api.VERSION)
    return dict(version["schema"]["openAPIV3Schema"])


def at(root: dict[str, Any], *path: str) -> dict[str, Any]:
    """The schema node at ``path``: ``*`` steps into a map's values (additionalProperties), ``[]`` into a list's items."""
    node = root
    for step in path:
        node = {"*": node.get("additionalProperties"), "[]": node.get("items")}.get(step) or node["properties"][step]
    return node


PLACES = [
    (api.ROBOTJOBS, ("spec",), resources.RobotJobSpec),
    (api.ROBOTJOBS, ("status",), resources.RobotJobStatus),
    (api.ROBOTJOBS, ("status", "rollout"), resources.Rollout),
    (api.ROBOTJOBS, ("status", "rollouts", "[]"), resources.RolloutRecord),
    (api.ROBOTJOBS, ("status", "rollouts", "[]", "monitor"), resources.MonitorVerdict),
    (api.ROBOTJOBS, ("status", "conditions", "[]"), resources.Condition),
    (api.ROBOTJOBS, ("status", "result"), resources.RobotJobResult),
    (api.ROBOTJOBS, ("status", "artifacts"), resources.JobArtifacts),
    (api.CELLS, ("spec",), resources.CellSpec),
    (api.CELLS, ("spec", "robot"), resources.CellArm),
    (api.CELLS, ("spec", "arms", "*"), resources.CellArm),
    (api.CELLS, ("spec", "cameras", "*"), resources.CellCamera),
    (api.CELLS, ("status",), resources.CellStatus),
    (api.CELLS, ("status", "conditions", "[]"), resources.Condition),
    (api.CELLS, ("status", "queue"), resources.CellQueue),
    (api.CELLQUOTAS, ("spec",), resources.CellQuotaSpec),
    (api.CELLQUOTAS, ("status",), resources.CellQuotaStatus),
    (api.CELLQUOTAS, ("status", "usage"), resources.QuotaUsage),
]


def wire_names(model: type[BaseModel]) -> dict[str, str]:
    return {field.alias or name: name for name, field in model.model_fields.items()}


@pytest.mark.parametrize(("plural", "path", "model"), PLACES, ids=lambda v: getattr(v, "__name__", None))
def test_every_field_of_a_model_is_a_property_of_its_crd_at_the_same_place(plural, path, model) -> None:
    node = at(schema(plural), *path)
    assert set(wire_names(model)) - set(node["properties"]) == set(), f"{model.__name__} reads fields the CRD lacks"


@pytest.mark.parametrize(("plural", "path", "model"), PLACES, ids=lambda v: getattr(v, "__name__", None))
def test_a_field_the_crd_requires_is_required_by_the_model(plural, path, model) -> None:
    node = at(schema(plural), *path)
    required = {wire for wire, name in wire_names(model).items() if model.model_fields[name].is_required()}
    assert required == set(node.get("required", [])) & set(wire_names(model))


def test_the_models_lower_bounds_are_the_crds() -> None:
    spec = at(schema(api.ROBOTJOBS), "spec")
    assert spec["properties"]["timeoutSeconds"]["minimum"] == 1
    cell = at(schema(api.CELLS), "spec")
    assert cell["properties"]["gracePeriodSeconds"]["minimum"] == 0
    with pytest.raises(ValueError, match="timeoutSeconds"):
        resources.RobotJobSpec.model_validate({"image": "i", "embodiment": "e", "timeoutSeconds": 0})
    with pytest.raises(ValueError, match="gracePeriodSeconds"):
        resources.CellSpec.model_validate({"embodiment": "e", "gracePeriodSeconds": -1})


def test_a_time_without_a_zone_is_read_as_utc() -> None:
    status = resources.RobotJobStatus.model_validate({"startedAt": "2026-11-29T10:00:00"})
    assert status.started_at is not None and status.started_at.utcoffset() is not None
    assert status.started_at.isoformat() == "2026-11-29T10:00:00+00:00"
