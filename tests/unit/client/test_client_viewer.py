"""Rerun packets from the log stream: however the agent publishes them, the SDK's packet comes back."""

from __future__ import annotations

import base64
from datetime import datetime, timezone

import pytest
from armnet_client.logwire import decode
from armnet_client.viewer import packet_document, packet_of
from armnet_runtime.markers import format_rerun
from armnet_runtime.rerun import ENCODING_JPEG, Entry, ImageData, Packet, encode_packet

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
