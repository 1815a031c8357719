"""Each platform package's public surface is its ``__all__``: other packages import nothing else.

A module another package imports is part of the package's contract with it; listing
it in ``__all__`` makes that a decision, and this test makes an unlisted import (a
reach past the surface) fail with the module's name. The SDK's packages
(``armnet_core``, ``armnet_runtime``, ``armnet_client``) are left out: their public
surface is the SDK's documented API, pinned name by name and signature by signature in
tests/unit/runtime/test_runtime_conformance.py.
"""

from __future__ import annotations

import importlib
import importlib.util

import grimp
import pytest

pytestmark = pytest.mark.unit

PLATFORM = ("armnet_sim", "armnet_connector", "armnet_launch", "armnet_node", "armnet_local",
            "armnet_operator", "armnet_fms", "armnet_cli")
ALL = ("armnet_core", "armnet_runtime", "armnet_client", *PLATFORM)


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return grimp.build_graph(*ALL, cache_dir=None)


def reaches(graph: grimp.ImportGraph, package: str) -> dict[str, set[str]]:
    """Module of ``package`` -> the modules of other packages that import it directly."""
    found: dict[str, set[str]] = {}
    for importer in graph.modules:
        if importer.split(".")[0] == package:
            continue
        for imported in graph.find_modules_directly_imported_by(importer):
            if imported.split(".")[0] == package:
                found.setdefault(imported, set()).add(importer)
    return found


@pytest.mark.parametrize("package", PLATFORM)
def test_other_packages_import_only_what_the_package_lists_in_all(graph: grimp.ImportGraph, package: str) -> None:
    public = set(importlib.import_module(package).__all__)

    past_the_surface = {
        module: sorted(importers) for module, importers in reaches(graph, package).items()
        if module != package and module.split(".")[1] not in public
    }

    assert past_the_surface == {}, f"list these in {package}.__all__ or import them through it"


@pytest.mark.parametrize("package", PLATFORM)
def test_every_module_listed_in_all_exists(package: str) -> None:
    module = importlib.import_module(package)
    for name in module.__all__:
        assert hasattr(module, name) or importlib.util.find_spec(f"{package}.{name}") is not None, name
