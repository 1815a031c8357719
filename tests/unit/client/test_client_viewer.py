"""Rerun packets from the log stream: however the agent publishes them, the SDK's packet comes back,
and each entry becomes the Rerun archetype it stands for (a malformed one is skipped, never trusted)."""

from __future__ import annotations

import base64
from datetime import datetime, timezone

import pytest
from armnet_client.logwire import decode
from armnet_client.viewer import (
    Jpeg,
    RawImage,
    Scalar,
    Skipped,
    application_id,
    entity_logs,
    packet_document,
    packet_of,
    timelines,
)
from armnet_runtime.markers import format_rerun
from armnet_runtime.rerun import (
    ENCODING_JPEG,
    ENCODING_RAW_U8,
    Entry,
    ImageData,
    Packet,
    encode_packet,
)

pytestmark = pytest.mark.unit

STORED = datetime(2026, 11, 24, tzinfo=timezone.utc)  # noqa: UP017
PACKET = Packet("uid", 1_700_000_000_000_000_000, 4, 1, (
    Entry("action.shoulder_pan.pos", scalar=12.5),
    Entry("observation.front", image=ImageData(2, 1, 3, ENCODING_JPEG, b"\xff\xd8jpeg")),
))


@pytest.mark.parametrize("payload", [
    base64.b64encode(encode_packet(PACKET)),
    format_rerun(encode_packet(PACKET)).encode(),
    encode_packet(PACKET),
], ids=["base64", "marker-line", "raw"])
def test_a_packet_decodes_whichever_way_it_was_published(payload: bytes) -> None:
    line = decode("logs.a.uid.rerun", payload, msg_id="uid:rerun:1", stream_seq=1, stored_at=STORED)

    assert packet_of(line) == PACKET


def test_other_lines_and_garbage_are_not_packets() -> None:
    assert packet_of(decode("logs.a.u.stdout", b"aGk=", msg_id=None, stream_seq=1, stored_at=STORED)) is None
    assert packet_of(decode("logs.a.u.rerun", b"\x07\x07", msg_id=None, stream_seq=1, stored_at=STORED)) is None


def test_the_dump_shape_lists_scalars_and_image_sizes() -> None:
    assert packet_document(PACKET) == {
        "job_id": "uid", "timestamp_ns": 1_700_000_000_000_000_000, "sequence": 4, "dropped": 1,
        "entries": [{"path": "action.shoulder_pan.pos", "scalar": 12.5},
                    {"path": "observation.front", "image": {"width": 2, "height": 1, "channels": 3,
                                                            "encoding": 1, "bytes": 6}}]}


def test_a_scalar_entry_is_logged_as_a_scalar() -> None:
    assert entity_logs(Entry("action.gripper.pos", scalar=3.5)) == Scalar("action.gripper.pos", 3.5)


def test_a_jpeg_entry_is_handed_to_rerun_still_encoded() -> None:
    entry = Entry("observation.front", image=ImageData(2, 1, 3, ENCODING_JPEG, b"\xff\xd8jpeg"))

    assert entity_logs(entry) == Jpeg("observation.front", b"\xff\xd8jpeg")


@pytest.mark.parametrize(("channels", "model"), [(1, "L"), (3, "RGB"), (4, "RGBA")])
def test_a_raw_image_keeps_its_declared_shape_and_gets_the_color_model_of_its_channels(
    channels: int, model: str
) -> None:
    entry = Entry("observation.wrist", image=ImageData(2, 1, channels, ENCODING_RAW_U8, bytes(2 * channels)))

    assert entity_logs(entry) == RawImage("observation.wrist", bytes(2 * channels), 2, 1, model)  # type: ignore[arg-type]


@pytest.mark.parametrize("image", [
    ImageData(4, 4, 3, ENCODING_RAW_U8, b"\x00" * 47),
    ImageData(0, 4, 3, ENCODING_RAW_U8, b""),
    ImageData(1, 1, 2, ENCODING_RAW_U8, b"\x00\x00"),
    ImageData(1, 1, 3, 9, b"\x00\x00\x00"),
], ids=["bytes-short-of-the-shape", "zero-width", "two-channels", "unknown-encoding"])
def test_an_image_the_viewer_cannot_show_as_declared_is_skipped_with_the_reason(image: ImageData) -> None:
    logged = entity_logs(Entry("observation.x", image=image))

    assert isinstance(logged, Skipped) and logged.path == "observation.x" and logged.reason


def test_the_application_id_is_the_job_name_in_letters_rerun_keeps_as_is() -> None:
    assert application_id("pick.v2-7x2k") == "armnet-pick-v2-7x2k"


def test_a_packets_time_and_frame_are_its_timestamp_and_sequence() -> None:
    assert timelines(PACKET) == (1_700_000_000.0, 4)


def test_times_and_frames_rerun_cannot_hold_are_clamped_not_allowed_to_end_the_replay() -> None:
    hostile = Packet("uid", (1 << 63) - 1, (1 << 64) - 1, 0)

    seconds, frame = timelines(hostile)
    assert seconds * 1e9 < 2**63 and frame == 2**63 - 1
    assert timelines(Packet("uid", -(1 << 63), 0, 0)) == (0.0, 0)
