"""Rerun packets: hand-written protobuf checked against the real protobuf runtime; the streamer."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import armnet_runtime
import numpy as np
import pytest
from armnet_runtime import rerun
from armnet_runtime.context import Context
from armnet_runtime.markers import parse_marker_line
from armnet_runtime.rerun import (
    ENCODING_JPEG,
    ENCODING_RAW_U8,
    Entry,
    ImageData,
    Packet,
    RerunStreamer,
    decode_packet,
    encode_packet,
    frame_entries,
)

pytestmark = pytest.mark.unit

PROTO = Path(armnet_runtime.__file__).with_name("rerun_packet.proto")

_SCALAR_TYPES = {
    "string": 9, "bytes": 12, "double": 1, "int64": 3, "uint64": 4, "uint32": 13,
}


def packet_class() -> Any:
    """Build the RerunPacket message class from rerun_packet.proto with the real protobuf runtime.

    A small reader of the .proto text (messages, oneofs, enums) fills a
    FileDescriptorProto, so the test checks the file the repository ships.
    """
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    text = re.sub(r"//[^\n]*", "", PROTO.read_text())
    package = re.search(r"package\s+([\w.]+);", text).group(1)  # type: ignore[union-attr]
    file_proto = descriptor_pb2.FileDescriptorProto(
        name="armnet_rerun_packet_test.proto", package=package, syntax="proto3"
    )
    enums = set()
    for name, body in re.findall(r"enum\s+(\w+)\s*\{([^}]*)\}", text):
        enums.add(name)
        enum = file_proto.enum_type.add(name=name)
        for value_name, number in re.findall(r"(\w+)\s*=\s*(\d+);", body):
            enum.value.add(name=value_name, number=int(number))
    for name, body in re.findall(r"message\s+(\w+)\s*\{((?:[^{}]|\{[^{}]*\})*)\}", text):
        message = file_proto.message_type.add(name=name)
        oneofs = {m.start(): m for m in re.finditer(r"oneof\s+(\w+)\s*\{([^}]*)\}", body)}
        oneof_fields: dict[str, int] = {}
        for index, match in enumerate(oneofs.values()):
            message.oneof_decl.add(name=match.group(1))
            for field_name in re.findall(r"\w+\s+(\w+)\s*=\s*\d+;", match.group(2)):
                oneof_fields[field_name] = index
        for label, type_name, field_name, number in re.findall(
            r"(repeated\s+)?([\w.]+)\s+(\w+)\s*=\s*(\d+);", body
        ):
            field = message.field.add(name=field_name, number=int(number))
            field.label = 3 if label else 1
            if type_name in _SCALAR_TYPES:
                field.type = _SCALAR_TYPES[type_name]
            else:
                field.type = 14 if type_name in enums else 11
                field.type_name = f".{package}.{type_name}"
            if field_name in oneof_fields:
                field.oneof_index = oneof_fields[field_name]
    pool = descriptor_pool.DescriptorPool()
    pool.Add(file_proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{package}.RerunPacket"))


SAMPLE = Packet(
    job_id="job-7",
    timestamp_ns=1_763_700_000_123_456_789,
    sequence=300,
    dropped=2,
    entries=(
        Entry("action.shoulder_pan.pos", scalar=-12.5),
        Entry("observation.zero", scalar=0.0),
        Entry("observation.front", image=ImageData(2, 1, 3, ENCODING_RAW_U8, bytes(range(6)))),
        Entry("observation.wrist", image=ImageData(640, 480, 3, ENCODING_JPEG, b"\xff\xd8jpeg")),
    ),
)


def test_the_real_protobuf_runtime_decodes_our_encoding() -> None:
    message = packet_class().FromString(encode_packet(SAMPLE))
    assert (message.job_id, message.timestamp_ns, message.sequence, message.dropped) == (
        "job-7", 1_763_700_000_123_456_789, 300, 2,
    )
    assert [e.path for e in message.entries] == [e.path for e in SAMPLE.entries]
    assert message.entries[0].WhichOneof("value") == "scalar"
    assert message.entries[0].scalar == -12.5
    assert message.entries[1].WhichOneof("value") == "scalar"  # a zero scalar is still present
    front = message.entries[2].image
    assert (front.width, front.height, front.channels, front.encoding) == (2, 1, 3, ENCODING_RAW_U8)
    assert front.data == bytes(range(6))
    assert message.entries[3].image.encoding == ENCODING_JPEG


def test_our_decoder_reads_what_the_real_protobuf_runtime_writes() -> None:
    cls = packet_class()
    message = cls(job_id="j", timestamp_ns=5, sequence=1, dropped=0)
    entry = message.entries.add(path="observation.cam")
    entry.image.width, entry.image.height, entry.image.channels = 1, 1, 1
    entry.image.encoding = ENCODING_RAW_U8
    entry.image.data = b"\x07"
    message.entries.add(path="action.x", scalar=3.25)
    decoded = decode_packet(message.SerializeToString())
    assert decoded == Packet("j", 5, 1, 0, (
        Entry("observation.cam", image=ImageData(1, 1, 1, ENCODING_RAW_U8, b"\x07")),
        Entry("action.x", scalar=3.25),
    ))


def test_encode_decode_round_trip() -> None:
    assert decode_packet(encode_packet(SAMPLE)) == SAMPLE


def test_a_truncated_packet_is_refused() -> None:
    with pytest.raises(ValueError, match="truncated"):
        decode_packet(encode_packet(SAMPLE)[:-3])


def test_frame_entries_follow_lerobots_rules() -> None:
    entries = frame_entries(
        {"state": np.array([1.0, 2.5]), "observation.front": np.zeros((4, 6, 3), np.uint8),
         "note": "skipped", "grip": np.float32(0.5)},
        {"shoulder_pan.pos": 10, "gripper.pos": [1, 2]},
        compress_images=False,
    )
    by_path = {e.path: e for e in entries}
    assert set(by_path) == {
        "observation.state_0", "observation.state_1", "observation.front", "observation.grip",
        "action.shoulder_pan.pos", "action.gripper.pos_0", "action.gripper.pos_1",
    }
    assert by_path["observation.state_1"].scalar == 2.5
    assert by_path["observation.grip"].scalar == 0.5
    front = by_path["observation.front"].image
    assert front == ImageData(6, 4, 3, ENCODING_RAW_U8, bytes(72))


def test_raw_images_keep_their_exact_pixels_and_chw_is_transposed() -> None:
    rng = np.random.default_rng(0)
    hwc = rng.integers(0, 255, (8, 10, 3), dtype=np.uint8)
    [entry] = frame_entries({"cam": np.transpose(hwc, (2, 0, 1))}, None, compress_images=False)
    assert entry.image is not None
    assert (entry.image.width, entry.image.height, entry.image.channels) == (10, 8, 3)
    assert entry.image.data == hwc.tobytes()


def test_float_images_in_unit_range_are_scaled_to_bytes() -> None:
    [entry] = frame_entries({"depth": np.full((2, 2), 1.0, np.float32)}, None, compress_images=False)
    assert entry.image == ImageData(2, 2, 1, ENCODING_RAW_U8, b"\xff" * 4)


def test_jpeg_images_decode_to_the_same_picture() -> None:
    import cv2

    image = np.zeros((32, 48, 3), np.uint8)
    image[:, :24] = (255, 0, 0)  # red left half, in RGB
    [entry] = frame_entries({"front": image}, None, compress_images=True, jpeg_quality=95)
    assert entry.image is not None and entry.image.encoding == ENCODING_JPEG
    decoded = cv2.cvtColor(cv2.imdecode(np.frombuffer(entry.image.data, np.uint8), 1), cv2.COLOR_BGR2RGB)
    assert decoded.shape == (32, 48, 3)
    assert np.abs(decoded.astype(int) - image.astype(int)).mean() < 8


def packets_from(out: str) -> list[Packet]:
    parsed = [parse_marker_line(line) for line in out.splitlines()]
    return [decode_packet(m.payload) for m in parsed if m is not None and m.kind == "rerun"]


def test_a_full_queue_drops_the_oldest_frames(capsys: pytest.CaptureFixture[str]) -> None:
    streamer = RerunStreamer("job-1", maxsize=3)
    for i in range(10):  # the worker is not running yet: the queue fills up
        streamer.submit({"i": i})
    assert streamer.dropped_total == 7
    streamer.start()
    streamer.stop()
    packets = packets_from(capsys.readouterr().out)
    assert [p.entries[0].scalar for p in packets] == [7.0, 8.0, 9.0]
    assert [p.sequence for p in packets] == [7, 8, 9]
    assert [p.dropped for p in packets] == [7, 0, 0]


def test_queue_size_comes_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ARMNET_RERUN_QUEUE_MAXSIZE", "2")
    assert RerunStreamer("j").maxsize == 2
    monkeypatch.setenv("ARMNET_RERUN_QUEUE_MAXSIZE", "zero")
    assert RerunStreamer("j").maxsize == rerun.DEFAULT_QUEUE_MAXSIZE
    monkeypatch.delenv("ARMNET_RERUN_QUEUE_MAXSIZE")
    assert RerunStreamer("j").maxsize == rerun.DEFAULT_QUEUE_MAXSIZE == 8


def test_a_frame_that_cannot_be_encoded_is_skipped_not_fatal(
    capsys: pytest.CaptureFixture[str],
) -> None:
    class Exploding:
        ndim = 1
        dtype = "float64"

        def __array__(self, *args: Any, **kwargs: Any) -> Any:
            raise RuntimeError("cannot read sensor")

    streamer = RerunStreamer("job-1")
    streamer.start()
    streamer.submit({"bad": Exploding()})
    streamer.submit({"good": 1.0})
    streamer.stop()
    packets = packets_from(capsys.readouterr().out)
    assert [p.entries[0].path for p in packets] == ["observation.good"]


def test_log_rerun_data_streams_in_the_background(capsys: pytest.CaptureFixture[str]) -> None:
    ctx = Context(job_id="job-9", embodiment="lerobot/so-101", task="t")
    ctx.log_rerun_data()  # nothing to send: no streamer is started
    assert ctx._rerun_streamer is None
    ctx.log_rerun_data({"x": 1.0}, {"y": 2.0})
    ctx._rerun_streamer.stop()
    [packet] = packets_from(capsys.readouterr().out)
    assert packet.job_id == "job-9"
    assert [(e.path, e.scalar) for e in packet.entries] == [("observation.x", 1.0), ("action.y", 2.0)]
