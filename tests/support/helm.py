"""The armnet Helm chart for tests: where it is, the real `helm` to run, its renders, and releases on a test bed.

`helm` is the one scripts/setup.d/35-helm.sh builds (``ARMNET_HELM`` overrides).
:func:`render` turns ``helm template`` into objects (cached), :func:`find` picks one
out; :func:`helm_on` runs helm against a test bed's API server, and
:func:`adopt_crds` lets a new release take over the CRDs an earlier one left
(docs/helm.md).
"""

from __future__ import annotations

import functools
import os
import subprocess
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pytest
import yaml
from armnet_testbed.kube import ControlPlane

REPO_ROOT = Path(__file__).resolve().parents[2]
CHART = REPO_ROOT / "helm" / "armnet"
ALL_OPTIONS = CHART / "ci" / "all-options-values.yaml"
HELM_CACHE = Path.home() / ".cache" / "armnet" / "helm"
#: The CRDs the chart installs (and keeps on uninstall).
CRDS = tuple(sorted(
    doc["metadata"]["name"]
    for path in (REPO_ROOT / "crds").glob("*.yaml")
    for doc in yaml.safe_load_all(path.read_text())
    if isinstance(doc, dict) and doc.get("kind") == "CustomResourceDefinition"
))
"""Every CRD the chart ships (the repository's crds/ is their single source)."""


def helm_binary() -> Path:
    """The helm built by setup (ARMNET_HELM overrides); a missing one fails, saying what to run."""
    override = os.environ.get("ARMNET_HELM")
    if override:
        return Path(override)
    current = HELM_CACHE / "current"
    path = HELM_CACHE / f"v{current.read_text().strip()}" / "bin" / "helm" if current.is_file() else None
    if path is None or not path.is_file():
        pytest.fail(f"helm is not built ({current} missing): run scripts/setup.sh "
                    "(step scripts/setup.d/35-helm.sh)", pytrace=False)
    return path


def helm(*args: str, input: str | None = None, check: bool = True) -> subprocess.CompletedProcess[str]:
    result = subprocess.run([str(helm_binary()), *args], input=input, capture_output=True, text=True,
                            timeout=120, check=False)
    if check and result.returncode != 0:
        raise AssertionError(f"helm {' '.join(args)} failed ({result.returncode}):\n{result.stderr}")
    return result


def render(release: str = "armnet", namespace: str = "armnet-system", *,
           values_files: Iterable[Path] = (), values: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """`helm template` into a list of objects; ``values`` (given last) win over the files.

    Renders are cached per arguments (a helm run costs ~0.5 s here); callers must not
    mutate what they get.
    """
    extra = yaml.safe_dump(values) if values is not None else None
    return _render(release, namespace, tuple(str(p) for p in values_files), extra)


@functools.lru_cache(maxsize=64)
def _render(release: str, namespace: str, values_files: tuple[str, ...], extra: str | None) -> list[dict[str, Any]]:
    args = ["template", release, str(CHART), "--namespace", namespace]
    for path in values_files:
        args += ["--values", path]
    if extra is not None:
        args += ["--values", "-"]
    out = helm(*args, input=extra).stdout
    return [doc for doc in yaml.safe_load_all(out) if doc]


def notes(k8s: ControlPlane, release: str = "armnet", namespace: str = "armnet-system", *,
          values: dict[str, Any] | None = None) -> str:
    """The release notes (templates/NOTES.txt) as ``helm install`` prints them; nothing is installed.

    ``helm template`` never renders NOTES.txt; a client-side dry-run install does, and it
    still asks an API server for its version (the test bed's), and refuses objects that exist
    there unowned: the bed's CRDs, so the notes are rendered with ``crds.install`` false.
    """
    out = helm_on(k8s, "install", release, str(CHART), "--namespace", namespace, "--dry-run=client",
                  values={**(values or {}), "crds": {"install": False}}).stdout
    assert "NOTES:" in out, f"helm printed no NOTES section:\n{out[-2000:]}"
    return out.split("NOTES:", 1)[1]


def find(objects: list[dict[str, Any]], kind: str, name_suffix: str = "") -> dict[str, Any]:
    matches = [o for o in objects if o["kind"] == kind and o["metadata"]["name"].endswith(name_suffix)]
    assert len(matches) == 1, f"expected one {kind} named *{name_suffix}, got {[m['metadata']['name'] for m in matches]}"
    return matches[0]


def env_of(container: dict[str, Any]) -> dict[str, Any]:
    return {e["name"]: e.get("value", e.get("valueFrom")) for e in container.get("env", [])}


def helm_on(k8s: ControlPlane, *args: str, values: dict[str, Any] | None = None) -> subprocess.CompletedProcess[str]:
    argv = [str(helm_binary()), *args, f"--kubeconfig={k8s.kubeconfig}"]
    if values is not None:
        argv += ["--values", "-"]
    result = subprocess.run(argv, input=yaml.safe_dump(values) if values is not None else None,
                            capture_output=True, text=True, timeout=180, check=False)
    assert result.returncode == 0, f"helm {' '.join(args)} failed:\n{result.stderr}"
    return result


def adopt_crds(k8s: ControlPlane, release: str, namespace: str) -> None:
    """docs/helm.md: how a new release takes over CRDs an earlier one left behind."""
    for crd in CRDS:
        k8s.kubectl("label", "crd", crd, "app.kubernetes.io/managed-by=Helm", "--overwrite")
        k8s.kubectl("annotate", "crd", crd, f"meta.helm.sh/release-name={release}",
                    f"meta.helm.sh/release-namespace={namespace}", "--overwrite")
