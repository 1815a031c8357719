"""Checked layers: the pure core never imports kopf, kubernetes or the agent."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

PACKAGE = Path(__file__).resolve().parents[3] / "operator" / "armnet_operator"
PURE = ["model", "args", "admission", "cell_checks", "health", "scheduling", "quota", "fairshare", "quota_parsing", "lifecycle", "conditions", "patches", "parsing",
        "reconcile", "leader", "settings", "errors", "requeue", "preflight", "duty_cycle"]
ROBOT_HOST = ("armnet_sim", "armnet_connector", "armnet_launch", "armnet_node", "armnet_local")
FORBIDDEN_IN_PURE = ("kopf", "kubernetes", *ROBOT_HOST, "prometheus_client", "aiohttp")


def imported_roots(path: Path) -> set[str]:
    roots = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split(".")[0])
    return roots


@pytest.mark.parametrize("module", PURE)
def test_pure_modules_import_no_kubernetes_client_kopf_or_agent(module: str) -> None:
    assert imported_roots(PACKAGE / f"{module}.py").isdisjoint(FORBIDDEN_IN_PURE)


def test_no_operator_module_imports_the_agent() -> None:
    for path in PACKAGE.glob("*.py"):
        assert imported_roots(path).isdisjoint(ROBOT_HOST), path.name


def test_kopf_is_imported_only_by_the_edge() -> None:
    users = {p.stem for p in PACKAGE.glob("*.py") if "kopf" in imported_roots(p)}
    assert users <= {"handlers", "cli"}
