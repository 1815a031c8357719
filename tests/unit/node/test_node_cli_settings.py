"""The agent's settings from flags and environment: where it (and the FMS) find NATS, what its
Cells say without it, and the connector's user.

``armnet dev up`` exports ``NATS_URL``; the chart sets each component's own variable.
Every program takes its flag, then its own variable, then ``NATS_URL``.
"""

from __future__ import annotations

import argparse

import pytest
from armnet_core.nats_url import nats_url_from
from armnet_fms import cli as fms_cli
from armnet_node import cli as agent_cli
from armnet_node.health import STREAMS_CONNECTED, StreamsProbe, streams_condition
from armnet_node.publish import NoLink, server_of, streams_probe

pytestmark = pytest.mark.unit

DEV_UP = "nats://127.0.0.1:4333"
OWN = "nats://agent:secret@nats.example:4222"


@pytest.mark.parametrize(("flag", "env", "expected"), [
    (None, {}, None),
    (None, {"NATS_URL": DEV_UP}, DEV_UP),
    (None, {"NATS_URL": DEV_UP, "ARMNET_AGENT_NATS_URL": OWN}, OWN),
    (None, {"NATS_URL": DEV_UP, "ARMNET_AGENT_NATS_URL": ""}, DEV_UP),
    ("nats://flag:4222", {"NATS_URL": DEV_UP, "ARMNET_AGENT_NATS_URL": OWN}, "nats://flag:4222"),
])
def test_the_flag_wins_then_the_programs_own_variable_then_nats_url(
    flag: str | None, env: dict[str, str], expected: str | None
) -> None:
    assert nats_url_from(flag, env, "ARMNET_AGENT_NATS_URL") == expected


def agent_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    agent_cli.add_arguments(parser)
    return parser.parse_args(argv)


def fms_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    fms_cli.add_arguments(parser)
    return parser.parse_args(argv)


def test_the_agent_takes_the_nats_url_armnet_dev_up_exports(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ARMNET_AGENT_NATS_URL", raising=False)
    monkeypatch.setenv("NATS_URL", DEV_UP)
    assert agent_args([]).nats_url == DEV_UP


def test_the_agents_own_variable_and_flag_still_win(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NATS_URL", DEV_UP)
    monkeypatch.setenv("ARMNET_AGENT_NATS_URL", OWN)
    assert agent_args([]).nats_url == OWN
    assert agent_args(["--nats-url", "nats://flag:4222"]).nats_url == "nats://flag:4222"


def test_without_any_nats_the_agent_runs_without_streams(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ARMNET_AGENT_NATS_URL", raising=False)
    monkeypatch.delenv("NATS_URL", raising=False)
    assert agent_args([]).nats_url is None


def test_the_fms_reads_the_same_environment_and_keeps_its_local_default(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ARMNET_FMS_NATS_URL", raising=False)
    monkeypatch.setenv("NATS_URL", DEV_UP)
    assert fms_args([]).nats_url == DEV_UP
    monkeypatch.setenv("ARMNET_FMS_NATS_URL", OWN)
    assert fms_args([]).nats_url == OWN
    monkeypatch.delenv("ARMNET_FMS_NATS_URL")
    monkeypatch.delenv("NATS_URL")
    assert fms_args([]).nats_url == fms_cli.DEFAULT_NATS_URL


def test_an_agent_without_nats_says_on_its_cells_that_the_operators_inputs_cannot_reach_them() -> None:
    condition = streams_condition(streams_probe(NoLink()))
    assert (condition.type, condition.status, condition.reason) == (STREAMS_CONNECTED, "False", "NatsNotConfigured")
    assert "Confirm reset" in condition.message and "ARMNET_AGENT_NATS_URL or NATS_URL" in condition.message


def test_an_agent_whose_nats_is_unreachable_names_the_server_but_never_its_password() -> None:
    condition = streams_condition(StreamsProbe(configured=True, connected=False, server=server_of(OWN)))
    assert (condition.status, condition.reason) == ("False", "NatsUnreachable")
    assert "nats.example:4222" in condition.message and "secret" not in condition.message


def test_a_connected_link_makes_the_condition_true() -> None:
    condition = streams_condition(StreamsProbe(configured=True, connected=True, server="127.0.0.1:4222"))
    assert (condition.status, condition.reason) == ("True", "Connected")


@pytest.mark.parametrize(("url", "server"), [
    ("nats://agent:pw@nats.armnet-system.svc:4222", "nats.armnet-system.svc:4222"),
    ("nats://127.0.0.1:4333", "127.0.0.1:4333"),
    ("tls://nats.example", "nats.example"),
    ("not a url", "its URL"),
    ("nats://[::1", "its URL"),
])
def test_the_server_shown_is_host_and_port_only(url: str, server: str) -> None:
    assert server_of(url) == server


def test_the_connector_user_is_a_numeric_uid_from_flag_or_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("ARMNET_AGENT_CONNECTOR_USER", raising=False)
    assert agent_args([]).connector_user == 65532
    monkeypatch.setenv("ARMNET_AGENT_CONNECTOR_USER", "1001")
    assert agent_args([]).connector_user == 1001
    with pytest.raises(SystemExit):
        agent_args(["--connector-user", "armnet"])
