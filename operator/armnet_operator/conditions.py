"""Kubernetes-convention conditions on status bodies, with the clock passed in.

``set_condition`` edits a ``status.conditions`` list in place and returns
whether anything changed, so callers patch only when needed. The transition
time moves only when ``status`` flips, as the API conventions ask; messages are
truncated so a chatty reason never bloats etcd.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from armnet_core.times import kube_time

MAX_MESSAGE = 1024


def find_condition(conditions: list[dict[str, Any]], type_: str) -> dict[str, Any] | None:
    return next((c for c in conditions if c.get("type") == type_), None)


def set_condition(
    conditions: list[dict[str, Any]],
    type_: str,
    status: bool,
    reason: str,
    message: str,
    now: datetime,
    observed_generation: int | None = None,
) -> bool:
    """Upsert one condition; True if the list changed."""
    wanted: dict[str, Any] = {
        "type": str(type_),
        "status": "True" if status else "False",
        "reason": str(reason),
        "message": message[:MAX_MESSAGE],
    }
    if observed_generation is not None:
        wanted["observedGeneration"] = observed_generation
    current = find_condition(conditions, type_)
    if current is None:
        conditions.append({**wanted, "lastTransitionTime": kube_time(now)})
        return True
    changed = False
    if current.get("status") != wanted["status"]:
        current["lastTransitionTime"] = kube_time(now)
        changed = True
    for field, value in wanted.items():
        if current.get(field) != value:
            current[field] = value
            changed = True
    return changed


def remove_condition(conditions: list[dict[str, Any]], type_: str) -> bool:
    before = len(conditions)
    conditions[:] = [c for c in conditions if c.get("type") != type_]
    return len(conditions) != before


def is_true(conditions: list[dict[str, Any]], type_: str) -> bool:
    current = find_condition(conditions, type_)
    return current is not None and current.get("status") == "True"
