"""Builders of RobotJob and Cell bodies as the apiserver returns them (for pure mapping tests)."""

from __future__ import annotations

from typing import Any

from armnet_core.api import API_VERSION


def a_robotjob(name: str = "pick-1", namespace: str = "team-a", **status: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "apiVersion": API_VERSION, "kind": "RobotJob",
        "metadata": {"name": name, "namespace": namespace, "uid": "0f3c-uid",
                     "creationTimestamp": "2026-11-24T10:00:00Z"},
        "spec": {"image": "ghcr.io/acme/pick:1.2", "embodiment": "lerobot/so-101", "args": {"seed": 3},
                 "timeoutSeconds": 60, "secrets": {}, "detach": False, "priority": 0, "cancel": False},
    }
    if status:
        body["status"] = status
    return body


def a_cell(name: str = "cell-1", **status: Any) -> dict[str, Any]:
    return {"apiVersion": API_VERSION, "kind": "Cell",
            "metadata": {"name": name, "creationTimestamp": "2026-11-24T09:00:00Z"},
            "spec": {"embodiment": "lerobot/so-101", "nodeName": "host-1"}, "status": status}
