"""Tagged JSON: the value encoding of the connector protocol (runtime/PROTOCOL.md).

Every argument, attribute value and return value that crosses a connector socket
goes through :func:`encode` on one side and :func:`decode` on the other. Plain
JSON stands for itself; anything JSON cannot carry exactly (numpy arrays and
scalars, bytes, tuples, dicts with non-string keys, non-finite floats, paths and
a fixed allow-list of LeRobot enums/dataclasses) becomes an object tagged with
the reserved key ``"__armnet__"``. Anything else is refused with
:class:`ProtocolError` rather than silently mangled, because a proxy that quietly
turned a value into its ``str`` would make the remote call do something else.

numpy and LeRobot are imported lazily: the SDK must import without them, and a
control loop at 100 Hz pays only for exact-type checks on plain values.

This module also owns the JSON text of a protocol line (:func:`dumps_line`,
:func:`loads_json`): ``orjson`` when it is installed (the ``fast`` extra: several
times faster than ``json`` on both ends of every call), the standard library
otherwise. Both give the same values: integers beyond 64 bits travel tagged, so
no JSON parser ever sees one.
"""

from __future__ import annotations

import base64
import binascii
import dataclasses
import enum
import functools
import importlib
import json
import math
import pathlib
from collections.abc import Callable
from typing import Any

from armnet_runtime.errors import ProtocolError

TAG = "__armnet__"
"""The reserved key that marks a tagged value."""

ENUM_TYPES: dict[str, str] = {
    "MotorNormMode": "lerobot.motors",
    "OperatingMode": "lerobot.motors.feetech",
    "TorqueMode": "lerobot.motors.feetech",
    "DriveMode": "lerobot.motors.feetech",
    "ColorMode": "lerobot.cameras.configs",
    "Cv2Rotation": "lerobot.cameras.configs",
    "Cv2Backends": "lerobot.cameras.configs",
}
"""Allow-listed LeRobot enums: type name -> the module the decoder imports it from."""

DATACLASS_TYPES: dict[str, str] = {
    "MotorCalibration": "lerobot.motors",
    "Motor": "lerobot.motors",
    "OpenCVCameraConfig": "lerobot.cameras.opencv",
}
"""Allow-listed LeRobot dataclasses: type name -> the module the decoder imports it from."""

_UNLOADED: Any = object()
_orjson: Any = _UNLOADED  # imported at first use: importing the SDK loads only stdlib and pydantic
_orjson_options = 0
_std_encode = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode
_std_decode = json.JSONDecoder().decode



def fast_codec() -> Any:
    """The ``orjson`` module when it is installed (None otherwise), imported at the first line."""
    global _orjson, _orjson_options
    if _orjson is _UNLOADED:
        try:
            module = importlib.import_module("orjson")
        except ImportError:
            module = None
        if module is not None:
            # Refuse, as json does, what tagged JSON never holds: dataclasses, datetimes, subclasses.
            _orjson_options = (
                module.OPT_APPEND_NEWLINE | module.OPT_PASSTHROUGH_DATACLASS
                | module.OPT_PASSTHROUGH_DATETIME | module.OPT_PASSTHROUGH_SUBCLASS
            )
        _orjson = module
    return _orjson

_INT64_MIN, _UINT64_MAX = -(2**63), 2**64 - 1
_MAX_INT_DIGITS = 4300
_NUMPY_KINDS = frozenset("biufc")
_NON_FINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}
_PLAIN_SCALARS = (str, int, bool, type(None))
_PLAIN_NO_INT = (str, bool, type(None))
_PLAIN_VALUES = frozenset((str, int, float, bool, type(None)))
_PLAIN_NO_INT_TYPES = frozenset(_PLAIN_NO_INT)
_STR_TYPE = frozenset((str,))
_FLOAT_TYPE = frozenset((float,))
_allowed_type_cache: dict[str, type | None] = {}


# --------------------------------------------------------------------------- encode


def encode(value: Any) -> Any:
    """Return the tagged-JSON form of ``value`` (something ``json.dumps`` accepts).

    Raises ``ProtocolError`` naming the offending type when ``value`` (or anything
    inside it) has no encoding.
    """
    kind = type(value)
    if kind in _PLAIN_NO_INT:
        return value
    if kind is int:
        return value if _INT64_MIN <= value <= _UINT64_MAX else {TAG: "int", "value": str(value)}
    if kind is float:
        return value if math.isfinite(value) else _encode_non_finite(value)
    if kind is dict:
        # A goal or position dict: str keys and finite floats, checked in C loops (a per-item
        # Python check was most of its encoding). A sum of finite floats is finite unless it
        # overflows to inf (then the per-item path decides); a nan or an inf makes it non-finite.
        items = value.values()
        if (
            set(map(type, value)) <= _STR_TYPE and TAG not in value
            and set(map(type, items)) <= _FLOAT_TYPE and math.isfinite(sum(items))
        ):
            return dict(value)
        for key in value:
            if type(key) is not str or key == TAG:
                return {TAG: "dict", "items": [[encode(k), encode(v)] for k, v in value.items()]}
        return {key: item if _is_plain(item) else encode(item) for key, item in value.items()}
    if kind is list:
        if set(map(type, value)) <= _PLAIN_NO_INT_TYPES:
            return list(value)
        return [item if _is_plain(item) else encode(item) for item in value]
    if kind is tuple:
        return {TAG: "tuple", "items": [encode(item) for item in value]}
    return _encode_other(value, kind)


def encode_items(items: tuple[Any, ...] | list[Any]) -> list[Any]:
    """``[encode(item) for item in items]`` as a list; plain strings, bools and None take no call.

    Why: the positional arguments of a control loop's call (``("Present_Position",)``)
    are usually their own encoding; a C loop finds that out.
    """
    if set(map(type, items)) <= _PLAIN_NO_INT_TYPES:
        return list(items)
    return list(map(encode, items))


def _is_plain(value: Any) -> bool:
    """True for a value that is its own encoding (a string, a finite float, a bool or None):
    containers skip the call to ``encode`` for these (a goal dict is all floats)."""
    kind = type(value)
    return kind in _PLAIN_NO_INT or (kind is float and math.isfinite(value))


def jsonable(value: Any) -> Any:
    """Alias of :func:`encode` (the name the LeRobot proxies use)."""
    return encode(value)


def _encode_non_finite(value: float) -> dict[str, Any]:
    text = "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return {TAG: "float", "value": text}


def _encode_other(value: Any, kind: type) -> Any:
    if kind.__module__ == "numpy":
        return _encode_numpy(value, kind)
    if isinstance(value, (dict, list, tuple)):
        # Subclasses (OrderedDict, defaultdict, namedtuple) travel as the base container.
        if isinstance(value, dict):
            return encode(dict(value))
        return encode(list(value) if isinstance(value, list) else tuple(value))
    if isinstance(value, (bytes, bytearray)):
        return {TAG: "bytes", "data": base64.b64encode(bytes(value)).decode("ascii")}
    if isinstance(value, pathlib.PurePath):
        return {TAG: "path", "value": str(value)}
    if isinstance(value, enum.Enum):
        if kind.__name__ in ENUM_TYPES and kind.__module__.startswith("lerobot."):
            return {TAG: "enum", "type": kind.__name__, "value": encode(value.value)}
    elif dataclasses.is_dataclass(value):
        if kind.__name__ in DATACLASS_TYPES and kind.__module__.startswith("lerobot."):
            fields = {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)}
            return {TAG: "dataclass", "type": kind.__name__, "fields": fields}
    elif isinstance(value, (int, float, str)):
        # A plain subclass (not an enum) stands for its base value, e.g. a str subclass.
        return encode(_base(kind)(value))
    raise ProtocolError(
        f"cannot send a {kind.__module__}.{kind.__qualname__} over the connector: supported values are "
        "JSON values, numpy arrays/scalars, bytes, tuples, dicts, paths and the LeRobot calibration/camera "
        "types listed in runtime/PROTOCOL.md"
    )


def _base(kind: type) -> type[int] | type[float] | type[str]:
    for base in (int, float, str):
        if issubclass(kind, base):
            return base
    raise TypeError(kind)


def _encode_numpy(value: Any, kind: type) -> dict[str, Any]:
    import numpy as np

    if isinstance(value, np.ndarray):
        array = _native(value)
        return {
            TAG: "ndarray",
            "dtype": array.dtype.name,
            "shape": list(array.shape),
            "data": base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii"),
        }
    if isinstance(value, np.generic):
        scalar = _native(np.asarray(value))
        return {TAG: "npscalar", "dtype": scalar.dtype.name, "data": base64.b64encode(scalar.tobytes()).decode("ascii")}
    raise ProtocolError(f"cannot send a numpy {kind.__qualname__} over the connector")


def _native(array: Any) -> Any:
    dtype = array.dtype
    if dtype.kind not in _NUMPY_KINDS:
        raise ProtocolError(
            f"cannot send a numpy array of dtype {dtype} over the connector: only bool, integer, "
            "float and complex dtypes are supported"
        )
    if not dtype.isnative:
        return array.astype(dtype.newbyteorder("="))
    return array


# --------------------------------------------------------------------------- decode


def decode(obj: Any) -> Any:
    """Turn tagged JSON (as parsed by ``json.loads``) back into the value it stands for.

    Raises ``ProtocolError`` for an unknown tag, an allow-list miss or a malformed
    tagged value.
    """
    kind = type(obj)
    if kind in _PLAIN_SCALARS or kind is float:
        return obj
    if kind is dict:
        tag = obj.get(TAG)
        if tag is None:
            # Plain values stand for themselves: only containers recurse (a goal dict is all floats).
            if set(map(type, obj.values())) <= _PLAIN_VALUES:
                return dict(obj)
            return {key: item if type(item) in _PLAIN_VALUES else decode(item) for key, item in obj.items()}
        decoder = _DECODERS.get(tag) if type(tag) is str else None
        if decoder is None:
            raise ProtocolError(f"unknown tagged value kind {tag!r} (expected one of {sorted(_DECODERS)})")
        try:
            return decoder(obj)
        except ProtocolError:
            raise
        except (KeyError, TypeError, ValueError, binascii.Error) as exc:
            raise ProtocolError(f"malformed tagged {tag!r} value: {exc!r}") from exc
    if kind is list:
        if set(map(type, obj)) <= _PLAIN_VALUES:
            return list(obj)
        return [item if type(item) in _PLAIN_VALUES else decode(item) for item in obj]
    raise ProtocolError(f"not a tagged-JSON value: {kind.__qualname__}")


_PLAIN_OR_DICT = frozenset((*_PLAIN_VALUES, dict))


def plain_arguments(items: list[Any]) -> bool:
    """True when ``items`` (a parsed JSON list) is its own decoding, so ``decode`` may be skipped.

    That is: every item is a plain value, or a dict without the tag whose values are all
    plain (a control loop's ``["Goal_Position", {motor: goal}]``). Checked with C loops;
    anything else (a tagged value, a nested container) returns False and is decoded.
    """
    kinds = set(map(type, items))
    if kinds <= _PLAIN_VALUES:
        return True
    if not kinds <= _PLAIN_OR_DICT:
        return False
    for item in items:
        if type(item) is dict and (TAG in item or not set(map(type, item.values())) <= _PLAIN_VALUES):
            return False
    return True


def _b64(obj: dict[str, Any]) -> bytes:
    data = obj["data"]
    if type(data) is not str:
        raise ProtocolError("tagged value 'data' must be a base64 string")
    return base64.b64decode(data, validate=True)


def _numpy_dtype(name: Any) -> Any:
    import numpy as np

    if type(name) is not str:
        raise ProtocolError(f"dtype must be a string, got {name!r}")
    try:
        dtype = np.dtype(name)
    except TypeError as exc:
        raise ProtocolError(f"unknown numpy dtype {name!r}") from exc
    if dtype.kind not in _NUMPY_KINDS:
        raise ProtocolError(f"numpy dtype {name!r} is not allowed on the wire")
    return dtype


def _decode_ndarray(obj: dict[str, Any]) -> Any:
    import numpy as np

    dtype = _numpy_dtype(obj["dtype"])
    shape = obj["shape"]
    if type(shape) is not list or not all(type(n) is int and n >= 0 for n in shape):
        raise ProtocolError(f"ndarray shape must be a list of non-negative ints, got {shape!r}")
    raw = _b64(obj)
    expected = math.prod(shape) * dtype.itemsize
    if len(raw) != expected:
        raise ProtocolError(f"ndarray data holds {len(raw)} bytes, shape {shape} of {dtype} needs {expected}")
    # bytearray makes the array writable, as a frame from a local camera would be.
    return np.frombuffer(bytearray(raw), dtype=dtype).reshape(shape)


def _decode_npscalar(obj: dict[str, Any]) -> Any:
    import numpy as np

    dtype = _numpy_dtype(obj["dtype"])
    raw = _b64(obj)
    if len(raw) != dtype.itemsize:
        raise ProtocolError(f"npscalar data holds {len(raw)} bytes, {dtype} needs {dtype.itemsize}")
    return np.frombuffer(raw, dtype=dtype)[0]


def _decode_bytes(obj: dict[str, Any]) -> bytes:
    return _b64(obj)


def _items(obj: dict[str, Any]) -> list[Any]:
    items = obj["items"]
    if type(items) is not list:
        raise ProtocolError("tagged value 'items' must be a list")
    return items


def _decode_tuple(obj: dict[str, Any]) -> tuple[Any, ...]:
    return tuple(decode(item) for item in _items(obj))


def _decode_dict(obj: dict[str, Any]) -> dict[Any, Any]:
    result: dict[Any, Any] = {}
    for pair in _items(obj):
        if type(pair) is not list or len(pair) != 2:
            raise ProtocolError(f"tagged dict items must be [key, value] pairs, got {pair!r}")
        result[decode(pair[0])] = decode(pair[1])
    return result


def _decode_float(obj: dict[str, Any]) -> float:
    text = obj["value"]
    if text not in _NON_FINITE:
        raise ProtocolError(f"tagged float must be 'nan', 'inf' or '-inf', got {text!r}")
    return _NON_FINITE[text]


def _decode_int(obj: dict[str, Any]) -> int:
    text = obj["value"]
    if type(text) is not str or not 0 < len(text) <= _MAX_INT_DIGITS:
        raise ProtocolError(f"tagged int 'value' must be a decimal string of at most {_MAX_INT_DIGITS} digits")
    return int(text)


def _decode_path(obj: dict[str, Any]) -> pathlib.Path:
    text = obj["value"]
    if type(text) is not str:
        raise ProtocolError("tagged path 'value' must be a string")
    return pathlib.Path(text)


def _allowed_type(name: Any, table: dict[str, str]) -> type | None:
    """The real LeRobot type for an allow-listed name, or None when LeRobot is absent."""
    if type(name) is not str or name not in table:
        raise ProtocolError(f"type {name!r} is not on the wire allow-list ({sorted(table)})")
    if name not in _allowed_type_cache:
        try:
            found = getattr(importlib.import_module(table[name]), name, None)
        except ImportError:
            found = None
        _allowed_type_cache[name] = found if isinstance(found, type) else None
    return _allowed_type_cache[name]


def _decode_enum(obj: dict[str, Any]) -> Any:
    cls = _allowed_type(obj["type"], ENUM_TYPES)
    value = decode(obj["value"])
    return value if cls is None else cls(value)


def _decode_dataclass(obj: dict[str, Any]) -> Any:
    cls = _allowed_type(obj["type"], DATACLASS_TYPES)
    raw_fields = obj["fields"]
    if type(raw_fields) is not dict:
        raise ProtocolError("tagged dataclass 'fields' must be an object")
    fields = {str(key): decode(item) for key, item in raw_fields.items()}
    if cls is None:
        return fields
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(fields) - set(known))
    if unknown:
        raise ProtocolError(f"{cls.__name__} has no field(s) {unknown}")
    instance = cls(**{name: item for name, item in fields.items() if known[name].init})
    for name, item in fields.items():
        if not known[name].init:
            object.__setattr__(instance, name, item)
    return instance


_DECODERS: dict[str, Callable[[dict[str, Any]], Any]] = {
    "ndarray": _decode_ndarray,
    "npscalar": _decode_npscalar,
    "bytes": _decode_bytes,
    "tuple": _decode_tuple,
    "dict": _decode_dict,
    "float": _decode_float,
    "int": _decode_int,
    "path": _decode_path,
    "enum": _decode_enum,
    "dataclass": _decode_dataclass,
}


# --------------------------------------------------------------------------- lines


def dumps_line(obj: Any) -> bytes:
    """``obj`` as one compact JSON line (with its newline); TypeError/ValueError when it has no JSON form."""
    fast = _orjson if _orjson is not _UNLOADED else fast_codec()
    if fast is not None:
        try:
            line: bytes = fast.dumps(obj, option=_orjson_options)
            return line
        except TypeError:
            pass  # the standard library gives the precise error (or encodes what orjson will not)
    return _std_encode(obj).encode() + b"\n"


def line_codec() -> tuple[Callable[[Any], bytes], Callable[[bytes], Any]]:
    """(dumps, loads) for a hot path to bind once: orjson's own C functions when installed.

    Why: ``dumps_line``/``loads_json`` are a Python call each around the codec, paid
    on both ends of every request. The bound ``dumps`` raises ``TypeError`` where
    ``dumps_line`` would fall back to the standard library: callers then call
    ``dumps_line``. Without orjson these are ``dumps_line`` and ``loads_json``.
    """
    fast = fast_codec()
    if fast is None:
        return dumps_line, loads_json
    return functools.partial(fast.dumps, option=_orjson_options), fast.loads


def loads_json(data: bytes) -> Any:
    """Parse one JSON document; ``ValueError`` (or ``RecursionError``) when ``data`` is not one."""
    fast = _orjson if _orjson is not _UNLOADED else fast_codec()
    if fast is not None:
        return fast.loads(data)
    return _std_decode(data.decode())
