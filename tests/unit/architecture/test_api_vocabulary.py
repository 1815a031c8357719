"""``armnet_core.api`` is the one definition of the API's vocabulary, in step with ``crds/``."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from armnet_core import api
from armnet_core.models import JobStatus

from tests.unit.architecture.crds import CRDS, crd

pytestmark = pytest.mark.unit

@pytest.mark.parametrize("plural", [api.ROBOTJOBS, api.CELLS, api.CELLQUOTAS])
def test_every_crd_serves_the_group_and_version_the_packages_use(plural: str) -> None:
    body = crd(plural)

    assert body["spec"]["group"] == api.GROUP
    assert [v["name"] for v in body["spec"]["versions"] if v.get("served")] == [api.VERSION]
    assert api.API_VERSION == f"{api.GROUP}/{api.VERSION}"


def test_the_phases_are_the_robotjob_crds_phase_enum_in_its_order() -> None:
    version = crd(api.ROBOTJOBS)["spec"]["versions"][0]
    phase = version["schema"]["openAPIV3Schema"]["properties"]["status"]["properties"]["phase"]

    assert tuple(phase["enum"]) == api.PHASES == tuple(s.value for s in JobStatus)


def test_active_and_terminal_phases_are_disjoint_phases() -> None:
    assert api.ACTIVE_PHASES | api.TERMINAL_PHASES <= set(api.PHASES)
    assert not api.ACTIVE_PHASES & api.TERMINAL_PHASES
    assert api.TERMINAL_PHASES == {"succeeded", "failed", "timeout", "cancelled", "preempted"}


def _status_enum(plural: str, *path: str) -> tuple[str, ...]:
    """The enum of a status field of the CRD serving ``plural`` (``path`` below ``status``)."""
    schema = crd(plural)["spec"]["versions"][0]["schema"]["openAPIV3Schema"]["properties"]["status"]
    for name in path:
        schema = schema["properties"][name]
    return tuple(schema["enum"])


def test_the_enums_are_the_crds_enums_in_their_order() -> None:
    assert tuple(api.JobPhase) == api.PHASES
    assert tuple(api.CellPhase) == _status_enum(api.CELLS, "phase")
    assert tuple(api.ArtifactsPhase) == _status_enum(api.ROBOTJOBS, "artifacts", "phase")


def test_the_enums_read_and_print_as_their_plain_values() -> None:
    """What ``enum.StrEnum`` does on Python 3.11, on the SDK's Python 3.10 too: a member is the
    string on the wire, in comparisons, sets and f-strings alike."""
    assert api.JobPhase.RUNNING == "running" and "running" in {api.JobPhase.RUNNING}
    assert str(api.CellPhase.READY) == f"{api.CellPhase.READY}" == "Ready"
    assert api.JobPhase(JobStatus.RUNNING.value) is api.JobPhase.RUNNING


PACKAGES = [CRDS.parent / p for p in ("runtime/src", "operator", "agent", "cli", "fms")]


def test_each_armnet_io_key_is_spelled_in_one_module_only() -> None:
    """A label, annotation or finalizer two processes share was spelled in each (and could drift apart):
    a key has one module that spells it; the others import its name (``armnet_core.api`` for keys on
    RobotJobs and Cells)."""
    spelled: dict[str, set[str]] = {}
    for root in PACKAGES:
        for path in root.rglob("*.py"):
            if "_pb2" in path.name:
                continue
            for key in re.findall(r"""["'](armnet\.io/[a-z][a-z0-9.-]*)["']""", path.read_text()):
                spelled.setdefault(key, set()).add(str(path.relative_to(CRDS.parent)))
    twice = {key: sorted(paths) for key, paths in spelled.items() if len(paths) > 1}
    assert twice == {}, f"keys spelled in more than one module: {twice}"


def _product_modules() -> Iterator[Path]:
    """The packages' modules outside ``armnet_core``, the one place the vocabulary is spelled."""
    for root in PACKAGES:
        for path in root.rglob("*.py"):
            if "_pb2" not in path.name and "armnet_core" not in path.parts:
                yield path


def test_no_armnet_io_key_is_spelled_outside_the_core() -> None:
    """Keys on objects, containers and pods that one process writes and another reads are declared in
    ``armnet_core.api``; a package that spells one again could drift from it unnoticed."""
    spelled = sorted(
        f"{path.relative_to(CRDS.parent)}: {key}"
        for path in _product_modules()
        for key in re.findall(r"""["'](armnet\.io/[a-z][a-z0-9.-]*)["']""", path.read_text())
    )
    assert spelled == []


#: Every value of the vocabulary's enums, and the one condition type that is not a health condition;
#: less a Pod's phases (Kubernetes' own: the pod launcher reads them), one of which ``Failed`` is too.
VOCABULARY = {
    *api.PHASES,
    *api.CellPhase,
    *api.CellConditionType,
    *api.ArtifactsPhase,
    api.STREAMS_CONNECTED_CONDITION,
} - {"Pending", "Running", "Succeeded", "Failed", "Unknown"}


def _names_a_phase_or_type(node: ast.expr) -> bool:
    """``x.phase``, ``phase``, ``body["phase"]``, ``c.get("type")``... : an expression whose value is
    a phase or a condition type by its name."""
    name: object = None
    if isinstance(node, ast.Attribute):
        name = node.attr
    elif isinstance(node, ast.Name):
        name = node.id
    elif isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant):
        name = node.slice.value
    elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
          and node.args and isinstance(node.args[0], ast.Constant)):
        name = node.args[0].value
    return isinstance(name, str) and (name.lower().endswith("phase") or name == "type")


def _words(node: ast.expr | None) -> Iterator[ast.Constant]:
    """The string constants of an expression that is one, a tuple, list or set of them, or ``a if c else b``."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        yield node
    elif isinstance(node, ast.Tuple | ast.List | ast.Set):
        for element in node.elts:
            yield from _words(element)
    elif isinstance(node, ast.IfExp):
        yield from _words(node.body)
        yield from _words(node.orelse)


def _vocabulary_literals(tree: ast.AST) -> Iterator[ast.Constant]:
    """The vocabulary's values written as literals where a phase or a condition type is meant:
    compared with one, written as one (``{"phase": ...}``, ``phase=...``, ``phase or ...``), or
    declared as a constant."""
    for node in ast.walk(tree):
        found: list[ast.Constant] = []
        if isinstance(node, ast.Compare) and any(map(_names_a_phase_or_type, [node.left, *node.comparators])):
            found = [word for side in (node.left, *node.comparators) for word in _words(side)]
        elif isinstance(node, ast.BoolOp) and _names_a_phase_or_type(node.values[0]):
            found = [word for value in node.values[1:] for word in _words(value)]
        elif isinstance(node, ast.Dict):
            found = [word for key, value in zip(node.keys, node.values, strict=True)
                     if isinstance(key, ast.Constant) and key.value in ("phase", "type") for word in _words(value)]
        elif isinstance(node, ast.keyword) and (node.arg or "").lower().endswith("phase"):
            found = list(_words(node.value))
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            found = list(_words(node.value))
        yield from (word for word in found if word.value in VOCABULARY)


def test_no_phase_or_condition_type_is_spelled_outside_the_core() -> None:
    """Phases and condition types are ``armnet_core.api``'s enums: a package comparing with or
    writing ``"running"`` or ``"InterlockClear"`` itself would not notice a renamed value."""
    spelled = sorted(
        f"{path.relative_to(CRDS.parent)}:{word.lineno}: {word.value!r}"
        for path in _product_modules()
        for word in _vocabulary_literals(ast.parse(path.read_text()))
    )
    assert spelled == []
