"""The CRDs in ``crds/`` as the architecture tests read them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

CRDS = Path(__file__).resolve().parents[3] / "crds"


def crd(plural: str) -> dict[str, Any]:
    """The CRD in ``crds/`` that serves ``plural``."""
    for path in CRDS.glob("*.yaml"):
        body: dict[str, Any] = yaml.safe_load(path.read_text())
        if body["spec"]["names"]["plural"] == plural:
            return body
    raise AssertionError(f"no CRD in crds/ serves {plural}")
