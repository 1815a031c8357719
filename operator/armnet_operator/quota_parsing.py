"""The boundary for CellQuotas: a body from the API server into a ``CellQuota`` and its ``Usage``.

The CRD schema rejects bad values at apply time; this guards against objects
stored before the schema (or written with validation off). A malformed quota
raises ``PermanentError`` naming the fields to fix, so the caller reports it
and goes on with the other quotas: a bad CellQuota never stops the operator.
A bad usage in status is read as no usage (it is rebuilt from now on).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from armnet_core.resources import CellQuotaSpec, QuotaUsage
from armnet_core.times import micro_time
from pydantic import ValidationError

from .errors import PermanentError
from .fairshare import Standing
from .quota import CellQuota, QuotaObject, QuotaPeriod, Usage


def parse_cell_quota(body: Mapping[str, Any]) -> CellQuota:
    """The quota, or ``PermanentError`` saying which fields of which CellQuota to fix."""
    meta = body.get("metadata") or {}
    name = str(meta.get("name") or "") if isinstance(meta, Mapping) else ""
    if not name:
        raise PermanentError("a CellQuota without metadata.name was ignored")
    raw = body.get("spec")
    if not isinstance(raw, Mapping):
        raise PermanentError(f"CellQuota {name!r} has no spec; it was ignored")
    try:
        spec = CellQuotaSpec.model_validate(dict(raw))
    except ValidationError as error:
        fields = "; ".join(
            f"spec.{'.'.join(map(str, e['loc']))}: {e['msg']}" if e["loc"] else f"spec: {e['msg']}"
            for e in error.errors())
        raise PermanentError(f"CellQuota {name!r} was ignored until fixed: {fields}") from None
    return CellQuota(
        name=name, namespace=spec.namespace, embodiment=spec.embodiment, nominal_cells=spec.nominal_cells,
        task=spec.task, borrowing_limit=spec.borrowing_limit, weight=spec.weight, cohort=spec.cohort,
        credits_cell_hours=spec.credits_cell_hours, period=None if spec.period is None else QuotaPeriod(spec.period),
        preempt_lower_priority=spec.preemption.within_quota == "LowerPriority",
        resource_version=str(meta.get("resourceVersion") or ""),
    )


def parse_usage(body: Mapping[str, Any]) -> Usage:
    """``status.usage``; absent or unreadable reads as no usage yet."""
    status = body.get("status")
    raw = status.get("usage") if isinstance(status, Mapping) else None
    if not isinstance(raw, Mapping):
        return Usage()
    try:
        usage = QuotaUsage.model_validate(dict(raw))
    except ValidationError:
        return Usage()
    return Usage(usage.decayed_cell_seconds, usage.period_cell_seconds, usage.period_start, usage.updated_at)


def usage_status(usage: Usage) -> dict[str, Any]:
    """``status.usage`` as the operator writes it back."""
    def stamp(value: Any) -> str | None:
        return None if value is None else micro_time(value)

    return {"decayedCellSeconds": round(usage.decayed_cell_seconds, 3),
            "periodCellSeconds": round(usage.period_cell_seconds, 3),
            "periodStart": stamp(usage.period_start), "updatedAt": stamp(usage.updated_at)}


def read_quota(body: Mapping[str, Any]) -> QuotaObject:
    """What the cache keeps of one CellQuota body; never raises on a malformed one."""
    meta = body.get("metadata")
    meta = meta if isinstance(meta, Mapping) else {}
    spec = body.get("spec")
    namespace = spec.get("namespace") if isinstance(spec, Mapping) else None
    try:
        quota: CellQuota | None = parse_cell_quota(body)
        problem = None
    except PermanentError as error:
        quota, problem = None, str(error)
    return QuotaObject(
        name=str(meta.get("name") or ""), quota=quota, usage=parse_usage(body), problem=problem,
        namespace=namespace if isinstance(namespace, str) else None,
        resource_version=str(meta.get("resourceVersion") or ""), uid=str(meta.get("uid") or ""),
    )


def standing_status(standing: Standing) -> dict[str, Any]:
    """The quota's ``status`` as the operator writes it (a merge patch of these fields)."""
    return {"cellsInUse": standing.cells_in_use, "borrowedCells": standing.borrowed_cells,
            "waitingJobs": standing.waiting_jobs, "usage": usage_status(standing.usage)}


__all__ = ["parse_cell_quota", "parse_usage", "read_quota", "standing_status", "usage_status"]
