"""Answers for attribute reads outside the allow-list: plain facts, a method's existence, or absence.

LeRobot code reads a few facts about a bus or camera that are not part of the
call surface (``bus.model_ctrl_table``, ``bus.port_handler.baudrate``,
``cam.rotation``, ``cam.capture_width``) and probes for optional names with
``hasattr``. This module decides what such a read gets, so a proxy behaves like
the object it stands for without ever handing out something that reaches the
hardware:

- a listed fact: its plain value (tables, numbers, enums), copied;
- ``port_handler`` / ``packet_handler``: a snapshot of their safe values, which
  the SDK shows as a read-only view (the handlers themselves drive the line);
- a method of the real class that a job may not call: reported as callable, so
  ``hasattr`` is True as on a bare arm and the *call* is what gets refused,
  with the allow-list's message;
- a name the real object does not have: ``AttributeError``;
- anything else (a data attribute holding a live helper): refused, ``NotAllowed``.
"""

from __future__ import annotations

import copy
import inspect
from typing import Any

from armnet_runtime.wire import encode

from .errors import RequestError, not_allowed
from .hardware import Handle

FACTS: dict[str, frozenset[str]] = {
    "FeetechMotorsBus": frozenset(
        {
            "model_ctrl_table", "model_baudrate_table", "model_encoding_table", "model_number_table",
            "model_resolution_table", "available_baudrates", "apply_drive_mode", "normalized_data",
        }
    ),
    "OpenCVCamera": frozenset({"rotation", "backend", "capture_width", "capture_height", "fourcc"}),
}
"""Per class: attributes whose value is plain data describing the device, safe to copy out."""


def _port_handler(handle: Handle) -> dict[str, Any]:
    handler = handle.obj.port_handler
    return {
        # The customer's endpoint, never the cell's device path.
        "port_name": handle.overrides.get("port"),
        "baudrate": int(getattr(handler, "baudrate", 0)),
        "is_open": bool(getattr(handler, "is_open", False)),
    }


def _packet_handler(handle: Handle) -> dict[str, Any]:
    handler = handle.obj.packet_handler
    version = handler.getProtocolVersion() if hasattr(handler, "getProtocolVersion") else None
    return {"protocol_version": version, "bus_protocol_version": handle.obj.protocol_version}


VIEWS = {"FeetechMotorsBus": {"port_handler": _port_handler, "packet_handler": _packet_handler}}
"""Per class: helpers that drive the hardware, shown as a snapshot of their safe values."""


def answer(handle: Handle, name: str, refusal: str) -> dict[str, Any]:
    """The ``getattr`` reply for ``name``, which the allow-list refused with ``refusal``.

    Never calls a method of the real object except the handlers' plain getters,
    and never returns a live object: facts are deep-copied before encoding.
    """
    if name.startswith("_"):
        raise not_allowed(refusal)
    cls = handle.class_name
    view = VIEWS.get(cls, {}).get(name)
    if view is not None:
        with handle.lock:
            return {"ok": True, "callable": False, "view": True, "value": encode(view(handle))}
    if name in FACTS.get(cls, frozenset()):
        with handle.lock:
            value = copy.deepcopy(getattr(handle.obj, name))
        return {"ok": True, "callable": False, "value": encode(value)}
    try:
        static = inspect.getattr_static(handle.obj, name)
    except AttributeError:
        raise RequestError("AttributeError", f"{cls} object has no attribute {name!r}") from None
    if callable(static) or isinstance(static, (staticmethod, classmethod)):
        return {"ok": True, "callable": True}
    raise not_allowed(refusal)
