"""Kubernetes-convention conditions on status bodies, with the clock passed in. Pure.

The operator upserts its conditions on RobotJobs (:func:`set_condition`) and the node
agent replaces its health conditions on Cells (:func:`merge_conditions`); both follow
one rule, :func:`transition_time`: ``lastTransitionTime`` moves only when ``status``
flips, as the API conventions ask, so "since when" stays true while reasons and
messages change. Every time is written with :func:`armnet_core.times.kube_time`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from datetime import datetime
from typing import Any, Protocol, TypeVar

from armnet_core.times import kube_time

#: A condition's message is cut to this many characters, so a chatty reason never bloats etcd.
MAX_MESSAGE = 1024


_Condition = TypeVar("_Condition", bound=Mapping[str, Any])


class ConditionFields(Protocol):
    """One condition as its writer decides it: everything but the transition time."""

    @property
    def type(self) -> str: ...
    @property
    def status(self) -> str: ...
    @property
    def reason(self) -> str: ...
    @property
    def message(self) -> str: ...


def find_condition(conditions: Iterable[_Condition], type_: str) -> _Condition | None:
    """The condition of ``type_`` in ``conditions`` (the object itself, to edit it), or None."""
    return next((c for c in conditions if c.get("type") == type_), None)


def transition_time(previous: Mapping[str, Any] | None, status: str, now: datetime) -> str | None:
    """A condition's ``lastTransitionTime`` once its status is ``status``: ``now`` if it is new or its
    status flips, else the one ``previous`` carries (None if it carries none)."""
    if previous is None or previous.get("status") != status:
        return kube_time(now)
    return previous.get("lastTransitionTime")


def set_condition(
    conditions: list[dict[str, Any]],
    type_: str,
    status: bool,
    reason: str,
    message: str,
    now: datetime,
    observed_generation: int | None = None,
) -> bool:
    """Upsert one condition in place, its message truncated; True if the list changed, so callers
    patch only when needed."""
    wanted: dict[str, Any] = {
        "type": str(type_),
        "status": "True" if status else "False",
        "reason": str(reason),
        "message": message[:MAX_MESSAGE],
    }
    if observed_generation is not None:
        wanted["observedGeneration"] = observed_generation
    current = find_condition(conditions, type_)
    stamp = transition_time(current, wanted["status"], now)
    if current is None:
        conditions.append({**wanted, "lastTransitionTime": stamp})
        return True
    if stamp is not None:
        wanted["lastTransitionTime"] = stamp
    changed = False
    for field, value in wanted.items():
        if current.get(field) != value:
            current[field] = value
            changed = True
    return changed


def merge_conditions(
    current: Sequence[Mapping[str, Any]], fresh: Sequence[ConditionFields], now: datetime
) -> list[dict[str, Any]]:
    """A new condition list: the ``fresh`` conditions (a writer's whole set, written as they are)
    after the ``current`` ones of other types, kept as they are. A fresh condition whose current
    one carries no transition time gets ``now``."""
    by_type = {str(c.get("type")): c for c in current}
    owned = {condition.type for condition in fresh}
    merged = [dict(c) for c in current if c.get("type") not in owned]
    for condition in fresh:
        stamp = transition_time(by_type.get(condition.type), condition.status, now)
        merged.append(
            {
                "type": condition.type,
                "status": condition.status,
                "reason": condition.reason,
                "message": condition.message,
                "lastTransitionTime": stamp or kube_time(now),
            }
        )
    return merged


def remove_condition(conditions: list[dict[str, Any]], type_: str) -> bool:
    """Drop the condition of ``type_``; True if there was one."""
    before = len(conditions)
    conditions[:] = [c for c in conditions if c.get("type") != type_]
    return len(conditions) != before


def is_true(conditions: Iterable[Mapping[str, Any]], type_: str) -> bool:
    current = find_condition(conditions, type_)
    return current is not None and current.get("status") == "True"


__all__ = [
    "MAX_MESSAGE",
    "ConditionFields",
    "find_condition",
    "is_true",
    "merge_conditions",
    "remove_condition",
    "set_condition",
    "transition_time",
]
