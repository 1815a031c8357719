"""Tagged-JSON codec: every kind of runtime/PROTOCOL.md round-trips exactly through real JSON."""

from __future__ import annotations

import json
import math
import pathlib
from typing import Any

import numpy as np
import pytest
from armnet_runtime.errors import ProtocolError
from armnet_runtime.wire import TAG, decode, encode, jsonable
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

pytestmark = pytest.mark.unit


def through_json(value: Any) -> Any:
    """Encode, serialise strictly (no NaN tokens), parse and decode: what the socket does."""
    return decode(json.loads(json.dumps(encode(value), allow_nan=False)))


def same(a: Any, b: Any) -> bool:
    """Exact equality that also compares types, numpy dtypes/shapes/bytes and NaN."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, np.generic):
        return a.dtype == b.dtype and a.tobytes() == b.tobytes()
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    return bool(a == b)


def test_camera_frame_round_trips_exactly() -> None:
    frame = np.random.default_rng(7).integers(0, 256, size=(480, 640, 3), dtype=np.uint8)
    wire = encode(frame)
    assert wire[TAG] == "ndarray" and wire["dtype"] == "uint8" and wire["shape"] == [480, 640, 3]
    back = through_json(frame)
    assert same(back, frame)
    back[0, 0, 0] ^= 1  # frames are writable, like a local camera's
    assert back.flags.c_contiguous


def test_non_contiguous_and_big_endian_arrays_round_trip_by_value() -> None:
    base = np.arange(24, dtype=np.int32).reshape(4, 6)
    view = base[:, ::2].T
    assert same(through_json(view), np.ascontiguousarray(view))
    big = np.arange(5, dtype=">u2")
    back = through_json(big)
    assert back.dtype == np.dtype("uint16") and back.tolist() == big.tolist()


def test_sync_read_dict_of_floats_is_plain_json() -> None:
    positions = {f"{name}.pos": 12.5 for name in ("shoulder_pan", "shoulder_lift", "elbow_flex")}
    assert encode(positions) == positions
    assert jsonable(positions) == positions


@pytest.mark.parametrize(
    ("value", "kind"),
    [
        ((1, "a", None), "tuple"),
        (b"\x00\xff", "bytes"),
        ({1: 2, 3: 4}, "dict"),
        ({TAG: "ndarray", "x": 1}, "dict"),
        (float("inf"), "float"),
        (float("-inf"), "float"),
        (pathlib.Path("/x/y"), "path"),
        (np.float32(1.5), "npscalar"),
        (np.int64(-3), "npscalar"),
        (np.bool_(True), "npscalar"),
    ],
)
def test_tagged_kinds(value: Any, kind: str) -> None:
    assert encode(value)[TAG] == kind
    assert same(through_json(value), value)


def test_container_subclasses_travel_as_their_base() -> None:
    import collections

    point = collections.namedtuple("point", "x y")
    value = [collections.OrderedDict(a=1), collections.defaultdict(list, {"b": [2]}), point(1, 2)]
    assert same(through_json(value), [{"a": 1}, {"b": [2]}, (1, 2)])


def test_nan_round_trips() -> None:
    back = through_json({"x": [float("nan")]})
    assert math.isnan(back["x"][0])


def test_lerobot_types_decode_to_the_real_classes() -> None:
    from lerobot.cameras.configs import ColorMode, Cv2Rotation
    from lerobot.cameras.opencv import OpenCVCameraConfig
    from lerobot.motors import Motor, MotorCalibration, MotorNormMode
    from lerobot.motors.feetech import DriveMode, OperatingMode, TorqueMode

    value = {
        "motors": {"gripper": Motor(6, "sts3215", MotorNormMode.RANGE_0_100)},
        "calibration": {"gripper": MotorCalibration(6, 0, -12, 2000, 3300)},
        "camera": OpenCVCameraConfig(
            index_or_path=pathlib.Path("/dev/video0"), fps=30, width=640, height=480,
            color_mode=ColorMode.BGR, rotation=Cv2Rotation.ROTATE_90,
        ),
        "modes": [OperatingMode.POSITION, TorqueMode.ENABLED, DriveMode.INVERTED],
    }
    back = through_json(value)
    assert back == value
    assert type(back["motors"]["gripper"].norm_mode) is MotorNormMode
    assert type(back["camera"].index_or_path) is pathlib.PosixPath
    assert encode(value["modes"][0]) == {TAG: "enum", "type": "OperatingMode", "value": 0}


def test_ranges_of_motion_tuple_and_ping_dict() -> None:
    value = ({"a": 1, "b": 2}, {"a": 4000, "b": 3000})
    assert same(through_json(value), value)
    assert same(through_json({1: 777, 2: 777}), {1: 777, 2: 777})


class NotWireable:
    pass


@pytest.mark.parametrize(
    "value",
    [NotWireable(), {1, 2}, object(), np.array(["a"]), np.array([object()]), lambda: 1],
    ids=["class", "set", "object", "str-array", "object-array", "lambda"],
)
def test_unsupported_values_are_refused(value: Any) -> None:
    with pytest.raises(ProtocolError, match="cannot send"):
        encode({"nested": [value]})


def test_foreign_enum_and_dataclass_are_refused() -> None:
    import dataclasses
    import enum

    class Colour(enum.Enum):
        RED = 1

    @dataclasses.dataclass
    class MotorCalibration:  # same name as LeRobot's, but not LeRobot's
        id: int

    with pytest.raises(ProtocolError):
        encode(Colour.RED)
    with pytest.raises(ProtocolError):
        encode(MotorCalibration(1))


@pytest.mark.parametrize(
    "wire",
    [
        {TAG: "pickle", "data": ""},
        {TAG: 3},
        {TAG: "dataclass", "type": "os.system", "fields": {}},
        {TAG: "enum", "type": "Subprocess", "value": 1},
        {TAG: "ndarray", "dtype": "uint8", "shape": [2, 2], "data": "AAE="},
        {TAG: "ndarray", "dtype": "object", "shape": [1], "data": "AA=="},
        {TAG: "ndarray", "dtype": "uint8", "shape": [-1], "data": ""},
        {TAG: "ndarray", "dtype": "uint8", "shape": [1], "data": "***"},
        {TAG: "ndarray", "dtype": "no-such-dtype", "shape": [1], "data": "AA=="},
        {TAG: "npscalar", "dtype": "float32", "data": "AA=="},
        {TAG: "bytes"},
        {TAG: "tuple", "items": "abc"},
        {TAG: "dict", "items": [[1, 2, 3]]},
        {TAG: "float", "value": "1e999"},
        {TAG: "path", "value": 3},
        {TAG: "dataclass", "type": "Motor", "fields": {"no_such_field": 1}},
    ],
)
def test_malformed_tagged_values_are_protocol_errors(wire: dict[str, Any]) -> None:
    with pytest.raises(ProtocolError):
        decode({"outer": [wire]})


def test_decoding_without_lerobot_gives_plain_values() -> None:
    import subprocess
    import sys

    script = (
        "import sys; sys.modules['lerobot'] = None\n"
        "from armnet_runtime.wire import decode\n"
        "print(decode({'__armnet__': 'dataclass', 'type': 'MotorCalibration', 'fields': "
        "{'id': 1, 'drive_mode': 0, 'homing_offset': 0, 'range_min': 0, 'range_max': 4095}}))\n"
        "print(decode({'__armnet__': 'enum', 'type': 'MotorNormMode', 'value': 'degrees'}))\n"
        "print('numpy' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == [
        "{'id': 1, 'drive_mode': 0, 'homing_offset': 0, 'range_min': 0, 'range_max': 4095}",
        "degrees",
        "False",
    ]


# ------------------------------------------------------------------ properties

json_leaves = st.one_of(
    st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True, allow_infinity=True),
    st.text(), st.binary(), st.builds(pathlib.Path, st.text(min_size=1).map(lambda s: "/" + s.replace("\x00", ""))),
)
numeric_dtypes = st.one_of(
    hnp.boolean_dtypes(), hnp.integer_dtypes(endianness="="), hnp.unsigned_integer_dtypes(endianness="="),
    hnp.floating_dtypes(endianness="="), hnp.complex_number_dtypes(endianness="="),
)
arrays = hnp.arrays(numeric_dtypes, hnp.array_shapes(min_dims=0, max_dims=3, max_side=4))
scalars = arrays.filter(lambda a: a.ndim == 0).map(lambda a: a[()])
keys = st.one_of(st.text(), st.integers(), st.just(TAG), st.tuples(st.integers(), st.text()))
values = st.recursive(
    st.one_of(json_leaves, arrays, scalars),
    lambda children: st.one_of(
        st.lists(children, max_size=4),
        st.tuples(children, children),
        st.dictionaries(st.text(), children, max_size=4),
        st.dictionaries(keys, children, max_size=4),
    ),
    max_leaves=12,
)


@settings(max_examples=150, deadline=None)
@given(values)
def test_any_supported_value_round_trips_exactly(value: Any) -> None:
    assert same(through_json(value), value)


@settings(max_examples=200, deadline=None)
@given(st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.text(),
                              st.floats(allow_nan=False, allow_infinity=False)),
                    lambda c: st.one_of(st.lists(c, max_size=4),
                                        st.dictionaries(st.text().filter(lambda k: k != TAG), c, max_size=4)),
                    max_leaves=12))
def test_plain_json_stands_for_itself(value: Any) -> None:
    assert encode(value) == value


@pytest.mark.parametrize("big", [2**64, -(2**63) - 1, 10**100])
def test_an_integer_beyond_64_bits_travels_tagged_and_comes_back_exact(big: int) -> None:
    assert encode(big) == {TAG: "int", "value": str(big)}
    assert through_json(big) == big and type(through_json(big)) is int


tag_names = st.sampled_from(["ndarray", "npscalar", "bytes", "tuple", "dict", "float", "int", "path", "enum", "dataclass"])
json_any = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), st.text(max_size=8),
              st.floats(allow_nan=False, allow_infinity=False)),
    lambda c: st.one_of(st.lists(c, max_size=3), st.dictionaries(st.text(max_size=6), c, max_size=3)),
    max_leaves=6,
)
hostile = st.fixed_dictionaries(
    {TAG: tag_names},
    optional={
        "dtype": st.one_of(st.sampled_from(["uint8", "float32", "object", "V8", "(2,)i4", "S3", "M8"]), json_any),
        "shape": st.one_of(st.lists(st.integers(-2, 5), max_size=3), json_any),
        "data": st.one_of(st.sampled_from(["", "AA==", "AAAAAA==", "!!"]), json_any),
        "items": json_any,
        "value": st.one_of(st.sampled_from(["nan", "degrees", "rgb", 0, 90, 7]), json_any),
        "type": st.one_of(st.sampled_from(["Motor", "MotorCalibration", "OpenCVCameraConfig", "ColorMode",
                                           "Cv2Rotation", "MotorNormMode", "os"]), json_any),
        "fields": st.one_of(st.dictionaries(st.sampled_from(["id", "model", "norm_mode", "index_or_path", "x"]),
                                            json_any, max_size=3), json_any),
    },
)


@settings(max_examples=300, deadline=None)
@given(hostile)
def test_hostile_tagged_values_only_ever_raise_protocol_error(wire: dict[str, Any]) -> None:
    try:
        decode(json.loads(json.dumps(wire)))
    except ProtocolError:
        pass


@settings(max_examples=150, deadline=None)
@given(values)
def test_a_protocol_line_carries_any_supported_value_exactly_whichever_codec_writes_it(value: Any) -> None:
    from armnet_runtime.wire import dumps_line, loads_json

    line = dumps_line({"value": encode(value)})
    assert line.endswith(b"\n") and b"\n" not in line[:-1]
    assert loads_json(line[:-1]) == json.loads(line)
    assert same(decode(loads_json(line[:-1])["value"]), value)


def test_without_orjson_the_standard_library_writes_the_same_lines(monkeypatch: pytest.MonkeyPatch) -> None:
    from armnet_runtime import wire

    payload = {"op": "call", "args": ["Goal_Position", {"elbow_flex": 12.5}], "kwargs": encode({"big": 2**70})}
    fast_line = wire.dumps_line(payload)
    monkeypatch.setattr(wire, "_orjson", None)  # as on an image without the 'fast' extra
    assert wire.dumps_line(payload) == fast_line
    assert wire.loads_json(fast_line[:-1]) == payload
    with pytest.raises(ValueError):
        wire.loads_json(b"{not json")


def test_the_bound_line_codec_writes_and_reads_the_lines_of_dumps_line(monkeypatch: pytest.MonkeyPatch) -> None:
    from armnet_runtime import wire

    payload = {"op": "call", "args": ["Goal_Position", {"elbow_flex": 12.5}], "kwargs": encode({"big": 2**70})}
    dumps, loads = wire.line_codec()
    assert dumps(payload) == wire.dumps_line(payload)
    assert loads(dumps(payload)) == payload
    with pytest.raises(ValueError):
        loads(b"{not json")
    monkeypatch.setattr(wire, "_orjson", None)  # without the 'fast' extra: the plain functions
    assert wire.line_codec() == (wire.dumps_line, wire.loads_json)


@pytest.mark.parametrize(
    "items",
    [("Present_Position",), ("Goal_Position", {"a": 1.5}), ("x", 2**70), (None, True, math.nan, (1, 2)), ()],
)
def test_encode_items_is_encode_item_by_item(items: tuple[Any, ...]) -> None:
    from armnet_runtime.wire import encode_items

    assert json.dumps(encode_items(items)) == json.dumps([encode(item) for item in items])


# -- the all-plain containers of a control loop, checked in C loops ----------------------


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_float_among_a_goal_dicts_floats_still_travels_tagged(bad: float) -> None:
    goals = {"shoulder_pan": 1.5, "elbow_flex": bad, "gripper": 30.0}
    assert encode(goals)["elbow_flex"] == {TAG: "float", "value": str(bad)}
    assert same(through_json(goals), goals)


def test_floats_whose_sum_overflows_are_still_plain_json() -> None:
    positions = {"shoulder_pan": 1e308, "elbow_flex": 1e308}
    assert encode(positions) == positions
    assert same(through_json(positions), positions)


def test_a_decoded_plain_container_is_a_new_object() -> None:
    wire_dict: dict[str, Any] = {"shoulder_pan": 1.0, "name": "arm", "on": True, "none": None, "ticks": 3}
    wire_list: list[Any] = ["Present_Position", 1.0, 2, None]
    decoded_dict, decoded_list = decode(wire_dict), decode(wire_list)
    assert decoded_dict == wire_dict and decoded_dict is not wire_dict
    assert decoded_list == wire_list and decoded_list is not wire_list


def test_an_encoded_plain_container_is_a_new_object() -> None:
    goals, names = {"shoulder_pan": 1.0}, ["shoulder_pan", "gripper"]
    assert encode(goals) == goals and encode(goals) is not goals
    assert encode(names) == names and encode(names) is not names
