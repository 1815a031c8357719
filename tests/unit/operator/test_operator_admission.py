"""The admission decision on a RobotJob: the same args rule as InvalidSpec, at the door.

Pure: an AdmissionReview dict in, a verdict out. The server around it is in
test_operator_webhook_server.py; the real API server calling it is in
tests/integration/test_operator_webhook_live.py.
"""

from __future__ import annotations

from typing import Any

import pytest
from armnet_core.api import API_VERSION, GROUP, ROBOTJOBS, VERSION
from armnet_operator.admission import MalformedReview, review_response, review_robotjob
from armnet_operator.args import MAX_ARGS_BYTES, MAX_ARGS_DEPTH, ArgsLimit, args_problem

pytestmark = pytest.mark.unit


def deep(levels: int) -> dict[str, Any]:
    value: dict[str, Any] = {"leaf": 1}
    for _ in range(levels - 1):
        value = {"a": value}
    return value


def review(args: Any = None, operation: str = "CREATE", sub_resource: str | None = None,
           uid: Any = "6f1c-uid", **request: Any) -> dict[str, Any]:
    spec: dict[str, Any] = {"image": "localhost/armnet-test:dev", "embodiment": "lerobot/so-101"}
    if args is not None:
        spec["args"] = args
    body: dict[str, Any] = {
        "uid": uid, "operation": operation,
        "kind": {"group": GROUP, "version": VERSION, "kind": "RobotJob"},
        "resource": {"group": GROUP, "version": VERSION, "resource": ROBOTJOBS},
        "object": {"apiVersion": API_VERSION, "kind": "RobotJob",
                   "metadata": {"name": "j", "namespace": "team-a"}, "spec": spec},
        **request,
    }
    if sub_resource:
        body["subResource"] = sub_resource
    return {"apiVersion": "admission.k8s.io/v1", "kind": "AdmissionReview", "request": body}


def test_a_job_within_the_limits_is_allowed() -> None:
    verdict = review_robotjob(review({"episodes": 3, "task": "pick", "poses": [[0.1, 0.2]] * 10}))
    assert verdict.allowed
    assert verdict.uid == "6f1c-uid"


def test_a_job_without_args_is_allowed() -> None:
    assert review_robotjob(review()).allowed


def test_args_exactly_at_the_depth_limit_are_allowed() -> None:
    assert review_robotjob(review(deep(MAX_ARGS_DEPTH))).allowed


@pytest.mark.parametrize(("args", "limit", "says"), [
    (deep(MAX_ARGS_DEPTH + 1), ArgsLimit.DEPTH, f"nested more than {MAX_ARGS_DEPTH} levels deep"),
    (deep(5_000), ArgsLimit.DEPTH, f"limit {MAX_ARGS_DEPTH}"),
    ({"blob": "x" * MAX_ARGS_BYTES}, ArgsLimit.SIZE, f"larger than {MAX_ARGS_BYTES} bytes"),
    ([1, 2, 3], ArgsLimit.TYPE, "must be an object"),
])
def test_args_beyond_a_limit_are_denied_naming_the_field_and_the_limit(
    args: Any, limit: ArgsLimit, says: str
) -> None:
    verdict = review_robotjob(review(args))
    assert not verdict.allowed
    assert verdict.limit is limit
    assert verdict.message.startswith("spec.args ")
    assert says in verdict.message


def test_the_webhook_and_the_operator_give_the_same_reason() -> None:
    """One rule: the message at the door is the InvalidSpec message the operator would write."""
    args = {"blob": "x" * (MAX_ARGS_BYTES + 1)}
    assert review_robotjob(review(args)).message == args_problem(args)


def test_updates_are_never_refused_so_an_old_oversized_job_can_still_lose_its_finalizer() -> None:
    assert review_robotjob(review(deep(100), operation="UPDATE")).allowed


def test_status_writes_are_never_refused() -> None:
    assert review_robotjob(review(deep(100), sub_resource="status")).allowed


def test_a_create_without_a_spec_is_left_to_the_schema() -> None:
    body = review()
    body["request"]["object"] = {"metadata": {"name": "j"}}
    assert review_robotjob(body).allowed


def test_a_denial_is_an_admission_review_with_the_uid_and_the_message() -> None:
    verdict = review_robotjob(review(deep(40)))
    answer = review_response(verdict)
    assert answer["apiVersion"] == "admission.k8s.io/v1"
    assert answer["kind"] == "AdmissionReview"
    assert answer["response"]["uid"] == "6f1c-uid"
    assert answer["response"]["allowed"] is False
    assert answer["response"]["status"]["code"] == 422
    assert answer["response"]["status"]["message"] == verdict.message


def test_an_allowance_carries_no_status() -> None:
    answer = review_response(review_robotjob(review({"a": 1})))
    assert answer["response"] == {"uid": "6f1c-uid", "allowed": True}


@pytest.mark.parametrize("body", [
    None, [], "AdmissionReview", 7,
    {"apiVersion": "admission.k8s.io/v1beta1", "kind": "AdmissionReview", "request": {"uid": "u"}},
    {"apiVersion": "admission.k8s.io/v1", "kind": "Pod", "request": {"uid": "u"}},
    {"apiVersion": "admission.k8s.io/v1", "kind": "AdmissionReview"},
    {"apiVersion": "admission.k8s.io/v1", "kind": "AdmissionReview", "request": []},
    review(uid=None), review(uid=""), review(uid=["u"]), review(uid="u" * 10_000),
])
def test_anything_but_a_v1_admission_review_with_a_uid_is_malformed(body: Any) -> None:
    with pytest.raises(MalformedReview):
        review_robotjob(body)


@pytest.mark.parametrize("job", [None, [], "x", {"spec": None}, {"spec": [1]}, {"spec": "args"}])
def test_an_object_of_the_wrong_shape_is_left_to_the_schema_not_a_crash(job: Any) -> None:
    body = review()
    body["request"]["object"] = job
    assert review_robotjob(body).allowed
