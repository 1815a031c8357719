"""What each operator action sends and writes, decided without I/O.

An action is checked against the fleet as the FMS last saw it (the button may
be stale: a reset that timed out, a job that ended), then turned into NATS
messages on the cell's ``fms.`` subjects, Kubernetes patches and an audit Event
naming the operator. ``kube`` and ``bus`` apply the result.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from armnet_core.api import STOPPED_BY_ANNOTATION

from .view import CellRow, PendingReset

CELL_NAME = re.compile(r"^[a-z0-9]([-a-z0-9.]{0,251}[a-z0-9])?$")


class ActionKind(StrEnum):
    CONFIRM_RESET = "confirm-reset"
    SUCCESS = "success"
    FAIL = "fail"
    #: Overrule the monitor's verdict on one rollout of the running job (from the list of verdicts).
    OVERRULE_SUCCESS = "overrule-success"
    OVERRULE_FAIL = "overrule-fail"
    STOP = "stop"
    CORDON = "cordon"
    UNCORDON = "uncordon"


class Refused(Exception):
    """The action does not apply to the cell as it is now; the message says why (shown to the operator)."""


@dataclass(frozen=True)
class AuditEvent:
    kind: str  # "RobotJob" | "Cell"
    namespace: str  # "default" for a Cell's events
    name: str
    uid: str
    reason: str
    message: str
    type: str = "Normal"


@dataclass(frozen=True)
class Plan:
    """Everything one action does; applied in order: messages, patches, event."""

    messages: tuple[tuple[str, bytes], ...] = ()
    cell_spec_patch: dict[str, Any] | None = None
    job_patch: tuple[str, str, dict[str, Any]] | None = None  # namespace, name, patch
    event: AuditEvent | None = None
    done: str = ""
    confirmed_request: str = ""  # the reset request this plan confirms: no longer pending once sent


def stop_reason(operator: str) -> str:
    return f"stopped by cell operator {operator}"


def _subject(cell: str, kind: str) -> str:
    if not CELL_NAME.match(cell):
        raise Refused(f"{cell[:60]!r} is not a cell name")
    return f"fms.{cell}.{kind}"


def _json(value: dict[str, Any]) -> bytes:
    return json.dumps(value, separators=(",", ":")).encode()


def _job_event(row: CellRow, reason: str, message: str, type_: str = "Normal") -> AuditEvent:
    assert row.job is not None
    return AuditEvent("RobotJob", row.job.namespace, row.job.name, row.job.uid, reason, message, type_)


def _cell_event(row: CellRow, uid: str, reason: str, message: str) -> AuditEvent:
    return AuditEvent("Cell", "default", row.name, uid, reason, message)


def _active_job(row: CellRow, what: str) -> None:
    if row.job is None or not row.job.active_phase:
        raise Refused(f"cell {row.name} runs no job now; nothing to {what}")


def plan_action(kind: ActionKind, row: CellRow, operator: str, now: float, *, request: str = "",
                cell_uid: str = "") -> Plan:
    """The plan for ``kind`` on the cell ``row`` by ``operator``, or :class:`Refused`.

    ``request`` is what the button was drawn for: the reset request id (Confirm
    reset) or the rollout index (Success/Fail), so a stale button never acts on
    a later reset or rollout.
    """
    if kind is ActionKind.CONFIRM_RESET:
        return _confirm_reset(row, operator, now, request)
    if kind in (ActionKind.SUCCESS, ActionKind.FAIL):
        _active_job(row, "mark")
        assert row.job is not None
        if row.job.rollout_index is None:
            raise Refused(f"job {row.job.key} has no rollout to mark")
        if request and request != str(row.job.rollout_index):
            raise Refused(f"this verdict was for rollout {request[:12]}; the job is on rollout "
                          f"{row.job.rollout_index} now: look again before marking it")
        if not row.job.rollout_active:
            raise Refused(f"rollout {row.job.rollout_index} of job {row.job.key} has ended; "
                          "a verdict can only be given while the rollout runs")
        if not row.job.outcome_controls:
            raise Refused(f"rollout {row.job.rollout_index} of job {row.job.key} asks for no verdict "
                          "(the job began it with outcome_controls=False)")
        success = kind is ActionKind.SUCCESS
        where = f"rollout {row.job.rollout_index}/{row.job.rollout_total}"
        verdict = "success" if success else "failure"
        return Plan(
            messages=((_subject(row.name, "outcome"),
                       _json({"success": success, "by": operator, "rollout": row.job.rollout_index})),),
            event=_job_event(row, "RolloutMarked", f"{where} marked {verdict} by cell operator {operator}"),
            done=f"{where} marked {verdict}",
        )
    if kind in (ActionKind.OVERRULE_SUCCESS, ActionKind.OVERRULE_FAIL):
        return _overrule(row, operator, request, kind is ActionKind.OVERRULE_SUCCESS)
    if kind is ActionKind.STOP:
        _active_job(row, "stop")
        assert row.job is not None
        reason = stop_reason(operator)
        # Only spec.cancel: the agent then trips the interlock, opens the grace window and ends
        # the job cancelled. The SDK's cooperative should_stop (fms.<cell>.stop) is not sent: a job
        # honouring it could return before the cancel lands and end "succeeded".
        return Plan(
            job_patch=(row.job.namespace, row.job.name,
                       {"metadata": {"annotations": {STOPPED_BY_ANNOTATION: operator}}, "spec": {"cancel": True}}),
            event=_job_event(row, "StoppedByCellOperator", reason, "Warning"),
            done=f"job {row.job.key} stopping: {reason}",
        )
    if kind in (ActionKind.CORDON, ActionKind.UNCORDON):
        cordon = kind is ActionKind.CORDON
        verb = "cordoned" if cordon else "uncordoned"
        return Plan(
            cell_spec_patch={"spec": {"unschedulable": cordon}},
            event=_cell_event(row, cell_uid, "Cordoned" if cordon else "Uncordoned",
                              f"cell {verb} by cell operator {operator}"),
            done=f"cell {row.name} {verb}",
        )
    raise Refused(f"unknown action {kind}")


def _overrule(row: CellRow, operator: str, request: str, success: bool) -> Plan:
    """The monitor's verdict on the rollout ``request`` names (``<index>@<startedAt>``, as the page showed it)
    replaced by the operator's: recorded by the agent in ``status.rollouts``, never sent to the job, which
    has acted on the monitor's verdict already. Only while the job runs (its agent keeps its record)."""
    _active_job(row, "overrule")
    assert row.job is not None
    judged = next((v for v in row.job.verdicts if v.request == request and v.monitor is not None), None)
    if judged is None:
        raise Refused(f"job {row.job.key} has no rollout the monitor judged as {request[:64]!r} among its latest "
                      "verdicts: look at the cell again")
    verdict = "success" if success else "failure"
    where = f"rollout {judged.index}/{judged.total}" if judged.total else f"rollout {judged.index}"
    monitor = f"the monitor's {judged.monitor}" + (f", score {judged.score:g}" if judged.score is not None else "")
    return Plan(
        messages=((_subject(row.name, "overrule"),
                   _json({"success": success, "by": operator, "rollout": judged.index,
                          "startedAt": judged.started_at})),),
        event=_job_event(row, "RolloutOverruled", f"{where} marked {verdict} by cell operator {operator} "
                                                  f"over {monitor}"),
        done=f"{where} marked {verdict} (over {monitor})",
    )


def _confirm_reset(row: CellRow, operator: str, now: float, request: str) -> Plan:
    pending: PendingReset | None = row.reset
    if pending is None or pending.expired(now):
        raise Refused(f"no reset is waiting on cell {row.name} (it may have timed out); nothing confirmed")
    if request != pending.request_id:
        raise Refused("this confirmation was for an earlier reset; look at the cell again before confirming")
    assert row.job is not None
    return Plan(
        messages=((_subject(row.name, "reset.confirm"), _json({"by": operator, "request": pending.request_id})),),
        event=_job_event(row, "ResetConfirmed", f"reset confirmed by cell operator {operator}"),
        done="reset confirmed",
        confirmed_request=pending.request_id,
    )
