"""Limits on ``RobotJob.spec.args``: how deep and how large a job's arguments may be.

The API server accepts any JSON up to its own limits (10,000 levels, ~3 MiB),
and a CRD schema cannot bound the depth or serialized size of a
``x-kubernetes-preserve-unknown-fields`` object. So this one rule is asked in
two places: the admission webhook (``admission``) refuses such a job at the
API server, and the operator fails one admitted anyway (no webhook answered)
with the reason, instead of binding a job that can never start. The walk is
iterative: a 10,000-level object costs no recursion (and stops early once a
limit is passed).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

MAX_ARGS_DEPTH = 32
"""Nesting levels of containers inside ``spec.args`` (``{"a": {"b": 1}}`` is 2)."""
MAX_ARGS_BYTES = 64 * 1024
"""Size of ``spec.args`` as compact JSON, in bytes (UTF-8)."""


class ArgsLimit(StrEnum):
    """Which rule a job's args broke (the ``limit`` label of the admission metrics)."""

    TYPE = "type"
    DEPTH = "depth"
    SIZE = "size"


@dataclass(frozen=True)
class ArgsViolation:
    limit: ArgsLimit
    message: str


def args_problem(args: Any) -> str | None:
    """Why these args can never be passed to the job, or None when they are within the limits."""
    violation = check_args(args)
    return None if violation is None else violation.message


def check_args(args: Any) -> ArgsViolation | None:
    """The one rule on ``spec.args``: the operator's ``InvalidSpec`` and the admission webhook both ask it."""
    if args is None:
        return None
    if not isinstance(args, Mapping):
        return ArgsViolation(ArgsLimit.TYPE,
                             f"spec.args must be an object (keyword arguments), not {type(args).__name__}")
    depth, size = measure(args, MAX_ARGS_DEPTH, MAX_ARGS_BYTES)
    if depth > MAX_ARGS_DEPTH:
        return ArgsViolation(ArgsLimit.DEPTH, (
            f"spec.args is nested more than {MAX_ARGS_DEPTH} levels deep (limit {MAX_ARGS_DEPTH}); "
            "flatten the arguments or pass large data through a dataset or model repository"))
    if size > MAX_ARGS_BYTES:
        return ArgsViolation(ArgsLimit.SIZE, (
            f"spec.args is larger than {MAX_ARGS_BYTES} bytes as JSON (limit {MAX_ARGS_BYTES}); "
            "pass large data through a dataset or model repository, not the job's arguments"))
    return None


def measure(value: Any, depth_cap: int, size_cap: int) -> tuple[int, int]:
    """(container depth, compact-JSON bytes) of ``value``; stops once either cap is passed."""
    depth = size = 0
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, Mapping):
            depth = max(depth, level)
            size += 2 + max(0, len(item) - 1)
            for key, child in item.items():
                size += _scalar_size(str(key)) + 1
                stack.append((child, level + 1))
        elif isinstance(item, list | tuple):
            depth = max(depth, level)
            size += 2 + max(0, len(item) - 1)
            stack.extend((child, level + 1) for child in item)
        else:
            size += _scalar_size(item)
        if depth > depth_cap or size > size_cap:
            break
    return depth, size


def _scalar_size(value: Any) -> int:
    try:
        return len(json.dumps(value, ensure_ascii=False).encode())
    except (TypeError, ValueError):
        return len(str(value).encode())
