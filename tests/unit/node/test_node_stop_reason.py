"""A job stopped from the FMS ends ``cancelled`` with the operator named in its result's error."""

from __future__ import annotations

from typing import Any

import pytest
from armnet_core.api import STOPPED_BY_ANNOTATION
from armnet_node.model import cancel_reason, parse_job

pytestmark = pytest.mark.unit


def job_obj(*, cancel: bool, annotations: dict[str, Any] | None = None) -> dict[str, Any]:
    return {"metadata": {"name": "eval-1", "namespace": "team-a", "uid": "u1", "annotations": annotations or {}},
            "spec": {"image": "img", "embodiment": "lerobot/so-101", "cancel": cancel},
            "status": {"phase": "running", "cellName": "so101-a"}}


def test_a_cancel_with_the_fms_annotation_names_the_cell_operator() -> None:
    job = parse_job(job_obj(cancel=True, annotations={STOPPED_BY_ANNOTATION: "maria"}))
    assert cancel_reason(job) == "stopped by cell operator maria"


def test_a_tenants_own_cancel_keeps_the_plain_reason() -> None:
    assert cancel_reason(parse_job(job_obj(cancel=True))) is None


def test_the_annotation_alone_does_not_make_a_reason() -> None:
    assert cancel_reason(parse_job(job_obj(cancel=False, annotations={STOPPED_BY_ANNOTATION: "maria"}))) is None


@pytest.mark.parametrize("name", ["", "x" * 65, "maria\nFAKE LOG LINE", "<b>maria</b>", 42])
def test_an_annotation_that_is_not_a_plain_operator_name_is_ignored(name: Any) -> None:
    assert cancel_reason(parse_job(job_obj(cancel=True, annotations={STOPPED_BY_ANNOTATION: name}))) is None
