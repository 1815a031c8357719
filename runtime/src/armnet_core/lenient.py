"""Read an API object with the core models, dropping only the parts that fail.

The cell operator's page (``armnet_fms``) must show what it can of a Cell or a
RobotJob in an incident, when one field of it is malformed: a status is written by
agents and tenants' jobs, and one bad rollout record must hide that record, not the
cell. :func:`read_leniently` validates with the same models every other reader uses
and, where validation fails, removes the smallest part the error points at and tries
again:

- a field of the wrong type or value is removed, so its default applies;
- an item of a list that is not what the list holds is removed from the list;
- an object missing a required field is removed whole (its parent decides again);
- the object itself missing a required field reads as ``None``.

Each round removes at least one part, and every error of a round is handled in that
round, so an object with fifty malformed rollouts takes one round, not fifty.
"""

from __future__ import annotations

import copy
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)

#: More rounds than any real object needs (each round removes every part that failed in it).
MAX_ROUNDS = 16

Path = tuple[Hashable, ...]


@dataclass(frozen=True)
class Reading(Generic[M]):
    """What :func:`read_parts` made of an object: the model, and the parts it left out to get it."""

    #: The object without the parts that failed; ``None`` if the object itself failed.
    value: M | None
    #: The parts removed, as paths: ``finishedAt``, ``rollouts[3]``, ``rollout.index``.
    dropped: tuple[str, ...] = ()


def read_parts(model: type[M], data: object) -> Reading[M]:
    """``data`` validated with ``model``, without the parts that fail, and which parts those were."""
    dropped: list[str] = []
    for _ in range(MAX_ROUNDS):
        try:
            return Reading(model.model_validate(data), tuple(dropped))
        except ValidationError as error:
            failed = {_existing_part(data, tuple(detail["loc"])) for detail in error.errors()}
            if () in failed:
                return Reading(None, tuple(dropped))
            data, removed = _without(data, failed)
            dropped.extend(_dotted(path) for path in removed)
    return Reading(None, tuple(dropped))


def read_leniently(model: type[M], data: object) -> M | None:
    """``data`` validated with ``model``, without the parts that fail; ``None`` if the object itself fails."""
    return read_parts(model, data).value


def _dotted(path: Path) -> str:
    text = ""
    for step in path:
        text += f"[{step}]" if isinstance(step, int) else f"{'.' if text else ''}{step}"
    return text


def _existing_part(data: object, loc: Path) -> Path:
    """The longest prefix of ``loc`` that names a part present in ``data``.

    An error's location may go past what the data holds: into a missing required
    field (its object is the part to remove) or into a union's branch name.
    """
    node: Any = data
    found: Path = ()
    for step in loc:
        if isinstance(node, dict) and step in node:
            node = node[step]
        elif isinstance(node, list) and isinstance(step, int) and 0 <= step < len(node):
            node = node[step]
        else:
            break
        found = (*found, step)
    return found


def _without(data: Any, parts: set[Path]) -> tuple[Any, list[Path]]:
    """A copy of ``data`` without ``parts``, and the parts removed, in their order in the object.

    A part inside another removed part goes with it and is not named twice.
    """
    outermost = sorted((p for p in parts if not any(p[:n] in parts for n in range(1, len(p)))), key=_dotted)
    pruned = copy.deepcopy(data)
    # Deepest and, within one list, highest index first: removing an item never moves one still to remove.
    for path in sorted(outermost, key=lambda p: (len(p), p[-1] if isinstance(p[-1], int) else -1), reverse=True):
        parent = pruned
        for step in path[:-1]:
            parent = parent[step]
        del parent[path[-1]]
    return pruned, outermost


__all__ = ["Reading", "read_leniently", "read_parts"]
