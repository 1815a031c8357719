"""The admission decision on a RobotJob: what the API server asks the webhook, answered without I/O.

kube-apiserver v1.34 cannot bound ``spec.args`` itself: it refuses CEL rules on
``x-kubernetes-preserve-unknown-fields`` content, and no schema keyword limits
depth or serialized size. So the operator serves a validating webhook that
asks the same rule as its ``InvalidSpec`` backstop (``args.check_args``): one
rule, two places it is enforced, never two rules that drift apart.

Only CREATE is judged. ``spec.args`` is immutable after creation (the CRD's
transition rule), and an UPDATE must never be refused here: removing the
finalizer of an old, oversized job has to keep working.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .args import ArgsLimit, check_args

REVIEW_API_VERSION = "admission.k8s.io/v1"
REVIEW_KIND = "AdmissionReview"
WEBHOOK_PATH = "/validate/robotjobs"
"""Where the API server posts reviews (the ValidatingWebhookConfiguration's ``path``)."""
_MAX_UID_CHARS = 128


class MalformedReview(ValueError):
    """The request is not an ``admission.k8s.io/v1`` AdmissionReview this webhook can answer."""


@dataclass(frozen=True)
class Verdict:
    uid: str
    allowed: bool
    limit: ArgsLimit | None = None
    message: str = ""


def review_robotjob(review: Any) -> Verdict:
    """Allow or deny the RobotJob in an AdmissionReview request; ``MalformedReview`` if it is not one."""
    if not isinstance(review, Mapping):
        raise MalformedReview("the body is not a JSON object")
    if review.get("apiVersion") != REVIEW_API_VERSION or review.get("kind") != REVIEW_KIND:
        raise MalformedReview(f"expected kind {REVIEW_KIND} of {REVIEW_API_VERSION} "
                              "(set admissionReviewVersions: [v1] in the webhook configuration)")
    request = review.get("request")
    if not isinstance(request, Mapping):
        raise MalformedReview("the AdmissionReview has no request")
    uid = request.get("uid")
    if not isinstance(uid, str) or not uid or len(uid) > _MAX_UID_CHARS:
        raise MalformedReview("the AdmissionReview request has no uid")
    if request.get("operation") != "CREATE" or request.get("subResource"):
        return Verdict(uid, allowed=True)
    job = request.get("object")
    spec = job.get("spec") if isinstance(job, Mapping) else None
    if not isinstance(spec, Mapping) or "args" not in spec:
        return Verdict(uid, allowed=True)  # the CRD's schema judges everything but args
    violation = check_args(spec["args"])
    if violation is None:
        return Verdict(uid, allowed=True)
    return Verdict(uid, allowed=False, limit=violation.limit, message=violation.message)


def review_response(verdict: Verdict) -> dict[str, Any]:
    """The AdmissionReview the API server expects back; a denial carries the message users see."""
    response: dict[str, Any] = {"uid": verdict.uid, "allowed": verdict.allowed}
    if not verdict.allowed:
        # kubectl prints: admission webhook "<name>" denied the request: <message>
        response["status"] = {"code": 422, "reason": "Invalid", "message": verdict.message}
    return {"apiVersion": REVIEW_API_VERSION, "kind": REVIEW_KIND, "response": response}
