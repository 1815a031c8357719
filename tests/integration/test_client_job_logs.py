"""``Client.logs`` / ``armnet logs`` on a RobotJob in the real apiserver, its lines in the real JetStream.

The job's lines are published as the agent contract fixes them, on the job's
UID; the client finds the UID from the RobotJob. Without a reachable NATS the
client says so once and follows the job's status instead.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import pytest
from armnet_core.models import JobSpec
from armnet_runtime.rerun import ENCODING_JPEG, Entry, ImageData, Packet, encode_packet
from armnet_testbed.natsd import NatsServer
from armnet_testbed.rrd import recorded

from tests.integration.client_bed import Publisher, Tenant, stdout_lines, terminal

pytestmark = pytest.mark.integration

SPEC = JobSpec(image="localhost/pick:dev", embodiment="test/client-logs")


@pytest.fixture
def tenant(k8s: Any, namespace: str) -> Tenant:
    return Tenant(k8s, namespace)


def test_logs_follow_a_jobs_stream_by_its_uid_until_the_terminal_status(
    tenant: Tenant, nats_server: str
) -> None:
    client = tenant.client()
    client.nats_url = nats_server
    client.submit(SPEC, name="streamed")
    uid = client.read("streamed").metadata.uid
    assert uid
    Publisher(nats_server, tenant.namespace, uid).publish(
        stdout_lines(1, 3) + [("progress", 1, b"halfway")] + terminal())

    lines = [(x.kind, x.text, x.source) for x in client.logs("streamed", follow=True)]

    assert lines == [("stdout", "line 1", "stream"), ("stdout", "line 2", "stream"),
                     ("stdout", "line 3", "stream"), ("progress", "halfway", "stream"),
                     ("status", "status: succeeded", "stream")]


def test_armnet_logs_prints_timestamped_lines(
    tenant: Tenant, nats_server: str, capsys: pytest.CaptureFixture[str]
) -> None:
    client = tenant.client()
    client.submit(SPEC, name="printed")
    uid = client.read("printed").metadata.uid
    assert uid
    Publisher(nats_server, tenant.namespace, uid).publish(
        [("stdout", 1, b"2026-11-24T10:00:00.250000Z hello"), ("stderr", 1, b"oops")])

    assert tenant.cli("logs", "printed", "--nats-url", nats_server) == 0

    out = capsys.readouterr().out.splitlines()
    assert out[0] == "2026-11-24T10:00:00.250Z hello"
    assert out[1].endswith("Z [stderr] oops") and len(out) == 2


def test_without_nats_the_client_says_so_once_and_follows_the_status(
    tenant: Tenant, caplog: pytest.LogCaptureFixture
) -> None:
    with NatsServer() as server:
        gone = server.url
    client = tenant.client()
    client.nats_url = gone
    client.submit(SPEC, name="no-nats")

    with caplog.at_level(logging.WARNING, logger="armnet_client"):
        lines = list(client.logs("no-nats", follow=False))

    assert [(x.kind, x.text, x.source) for x in lines] == [("status", "status: submitted", "status")]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "following the job's status instead" in warnings[0]


def test_armnet_view_dump_decodes_the_jobs_rerun_packets_from_the_stream(
    tenant: Tenant, nats_server: str, capsys: pytest.CaptureFixture[str]
) -> None:
    client = tenant.client()
    client.submit(SPEC, name="viewed")
    uid = client.read("viewed").metadata.uid
    assert uid
    packets = [Packet(uid, 1_700_000_000_000_000_000 + i, i, 0, (Entry("action.gripper.pos", scalar=float(i)),))
               for i in range(3)]
    Publisher(nats_server, tenant.namespace, uid).publish(
        [("stdout", 1, b"not a packet")]
        + [("rerun", i + 1, encode_packet(p)) for i, p in enumerate(packets)])

    assert tenant.cli("view", "viewed", "--dump", "--nats-url", nats_server) == 0

    dumped = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [d["sequence"] for d in dumped] == [0, 1, 2]
    assert dumped[2]["entries"] == [{"path": "action.gripper.pos", "scalar": 2.0}]


def test_armnet_view_save_writes_the_packets_from_the_stream_into_an_rrd_rerun_reads_back(
    tenant: Tenant, nats_server: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    require_rerun()
    client = tenant.client()
    client.submit(SPEC, name="saved")
    uid = client.read("saved").metadata.uid
    assert uid
    packets = [Packet(uid, 1_700_000_000_000_000_000 + i, i, 0, (
        Entry("action.gripper.pos", scalar=float(i)),
        Entry("observation.front", image=ImageData(2, 1, 3, ENCODING_JPEG, b"\xff\xd8" + bytes([i]))),
    )) for i in range(3)]
    Publisher(nats_server, tenant.namespace, uid).publish(
        [("rerun", i + 1, encode_packet(p)) for i, p in enumerate(packets)])
    out = tmp_path / "out.rrd"

    assert tenant.cli("view", "saved", "--save", str(out), "--nats-url", nats_server) == 0

    assert recorded(out) == {
        "/action.gripper.pos": [(0, 0.0), (1, 1.0), (2, 2.0)],
        "/observation.front": [(i, ("encoded", "image/jpeg", b"\xff\xd8" + bytes([i]))) for i in range(3)],
    }
    assert f"3 packets to {out}" in capsys.readouterr().err


def require_rerun() -> None:
    """rerun-sdk is installed by scripts/setup.sh: missing, it is a failure with the fix, not a skip."""
    import importlib.util

    if importlib.util.find_spec("rerun") is None:
        pytest.fail("rerun-sdk is missing: run scripts/setup.sh (or pip install 'armnet-runtime[view]')",
                    pytrace=False)
