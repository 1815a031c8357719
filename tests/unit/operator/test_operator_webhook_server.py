"""The admission webhook's HTTPS server: real TLS, real HTTP, hostile bodies.

In-process (aiohttp on loopback, a certificate from the test bed's CA); the
API server calling it is tests/integration/test_operator_webhook_live.py.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import shutil
import ssl
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from armnet_operator.admission import WEBHOOK_PATH
from armnet_operator.cli import add_arguments, run
from armnet_operator.errors import PermanentError
from armnet_operator.metrics import Metrics
from armnet_operator.webhook import MAX_REVIEW_BYTES, AdmissionWebhook
from armnet_testbed.pki import Pki, create_pki

pytestmark = pytest.mark.unit


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return create_pki(tmp_path_factory.mktemp("webhook-pki"))


@pytest.fixture
def cert_files(pki: Pki, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of a serving pair for 127.0.0.1 that a test may overwrite."""
    cert, key = tmp_path / "tls.crt", tmp_path / "tls.key"
    shutil.copy(pki.server_cert, cert)
    shutil.copy(pki.server_key, key)
    return cert, key


class Served:
    def __init__(self, webhook: AdmissionWebhook, session: aiohttp.ClientSession, ca: Path) -> None:
        self.webhook = webhook
        self.session = session
        self.url = f"https://127.0.0.1:{webhook.port}{WEBHOOK_PATH}"
        self.ca = ca

    async def post(self, body: bytes) -> tuple[int, Any]:
        async with self.session.post(self.url, data=body, headers={"Content-Type": "application/json"}) as reply:
            text = await reply.text()
            return reply.status, (json.loads(text) if reply.content_type == "application/json" else text)

    async def served_certificate(self) -> bytes:
        context = ssl.create_default_context(cafile=str(self.ca))
        _reader, writer = await asyncio.open_connection("127.0.0.1", self.webhook.port, ssl=context)
        der = writer.get_extra_info("ssl_object").getpeercert(binary_form=True)
        writer.close()
        return bytes(der)

    def count(self, metric: str, label: str, value: str) -> float:
        sample = self.webhook.metrics.registry.get_sample_value(metric, {label: value})
        return float(sample or 0)


async def serving(cert_files: tuple[Path, Path], ca: Path, cert_check_seconds: float = 30.0) -> AsyncIterator[Served]:
    webhook = AdmissionWebhook(Metrics(), str(cert_files[0]), str(cert_files[1]), "127.0.0.1", 0,
                               cert_check_seconds=cert_check_seconds)
    await webhook.start()
    context = ssl.create_default_context(cafile=str(ca))  # the API server checks the caBundle the same way
    try:
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=context)) as session:
            yield Served(webhook, session, ca)
    finally:
        await webhook.stop()


Scenario = Callable[[Served], Awaitable[None]]


@pytest.fixture
def serve(cert_files: tuple[Path, Path], pki: Pki) -> Callable[[Scenario], None]:
    """Run one scenario against a fresh server (asyncio.run: the suite has no async test plugin)."""
    def run(scenario: Scenario) -> None:
        async def main() -> None:
            async for s in serving(cert_files, pki.ca_cert):
                await scenario(s)
        asyncio.run(main())
    return run


def review_bytes(args_json: str) -> bytes:
    """Built as text so hostile nesting costs the test nothing."""
    return (
        '{"apiVersion":"admission.k8s.io/v1","kind":"AdmissionReview","request":{"uid":"u-1",'
        '"operation":"CREATE","object":{"kind":"RobotJob","spec":{"image":"i","embodiment":"e","args":'
        + args_json + "}}}}"
    ).encode()


def nested(levels: int) -> str:
    return '{"a":' * (levels - 1) + "1" + "}" * (levels - 1)


def test_a_deep_job_is_denied_over_tls_with_the_limit_in_the_message(serve: Callable[[Scenario], None]) -> None:
    async def scenario(served: Served) -> None:
        status, answer = await served.post(review_bytes(nested(40)))
        assert status == 200
        assert answer["response"]["uid"] == "u-1"
        assert answer["response"]["allowed"] is False
        assert "spec.args is nested more than 32 levels deep" in answer["response"]["status"]["message"]
        assert served.count("armnet_admission_requests_total", "outcome", "denied") == 1
        assert served.count("armnet_admission_rejections_total", "limit", "depth") == 1
    serve(scenario)


def test_a_normal_job_is_allowed_and_counted(serve: Callable[[Scenario], None]) -> None:
    async def scenario(served: Served) -> None:
        status, answer = await served.post(review_bytes('{"episodes":3}'))
        assert (status, answer["response"]["allowed"]) == (200, True)
        assert served.count("armnet_admission_requests_total", "outcome", "allowed") == 1
    serve(scenario)


def test_a_body_over_the_cap_is_refused_unread_and_the_server_keeps_answering(serve: Callable[[Scenario], None]) -> None:
    async def scenario(served: Served) -> None:
        status, _ = await served.post(review_bytes('"' + "x" * MAX_REVIEW_BYTES + '"'))
        assert status == 413
        assert served.count("armnet_admission_requests_total", "outcome", "malformed") == 1
        assert (await served.post(review_bytes("{}")))[1]["response"]["allowed"] is True
    serve(scenario)


def test_json_nested_beyond_any_decoder_is_a_400_not_a_crash(serve: Callable[[Scenario], None]) -> None:
    async def scenario(served: Served) -> None:
        status, answer = await served.post(review_bytes(nested(200_000)))
        assert status == 400
        assert "not a JSON AdmissionReview" in answer["error"]
        assert (await served.post(review_bytes("{}")))[1]["response"]["allowed"] is True
    serve(scenario)


@pytest.mark.parametrize("body", [b"", b"\xff\xfe", b"[1,2", b"null", b'{"kind":"AdmissionReview"}'])
def test_garbage_gets_a_400_saying_what_was_expected(serve: Callable[[Scenario], None], body: bytes) -> None:
    async def scenario(served: Served) -> None:
        status, answer = await served.post(body)
        assert status == 400
        assert len(answer["error"]) <= 200
    serve(scenario)


def test_a_rotated_certificate_is_served_without_a_restart(
    cert_files: tuple[Path, Path], pki: Pki
) -> None:
    async def scenario() -> None:
        async for served in serving(cert_files, pki.ca_cert, cert_check_seconds=0.05):
            before = await served.served_certificate()
            new_cert, new_key = pki.serving_cert("webhook-rotated", ("127.0.0.1",))
            shutil.copy(new_key, cert_files[1])
            shutil.copy(new_cert, cert_files[0])
            for _ in range(100):
                await asyncio.sleep(0.05)
                if await served.served_certificate() != before:
                    break
            assert await served.served_certificate() == ssl.PEM_cert_to_DER_cert(new_cert.read_text())
            assert (await served.post(review_bytes("{}")))[1]["response"]["allowed"] is True
    asyncio.run(scenario())


def test_a_missing_certificate_fails_at_start_saying_what_to_mount(tmp_path: Path) -> None:
    with pytest.raises(PermanentError, match="serving certificate .*tls.crt.*webhook-port 0"):
        AdmissionWebhook(Metrics(), str(tmp_path / "tls.crt"), str(tmp_path / "tls.key"), "127.0.0.1", 0)


def operator_args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(list(argv))


def test_the_operator_exits_2_naming_the_files_when_the_certificate_cannot_load(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    args = operator_args("--webhook-port", "9443", "--webhook-cert-file", str(tmp_path / "tls.crt"),
                         "--webhook-key-file", str(tmp_path / "tls.key"))
    assert run(args) == 2
    assert str(tmp_path / "tls.crt") in caplog.text


def test_a_webhook_port_without_a_certificate_is_refused_at_start(caplog: pytest.LogCaptureFixture) -> None:
    assert run(operator_args("--webhook-port", "9443")) == 2
    assert "needs webhook_cert_file and webhook_key_file" in caplog.text


def test_a_port_in_use_fails_start_saying_which(cert_files: tuple[Path, Path]) -> None:
    async def scenario() -> None:
        first = AdmissionWebhook(Metrics(), str(cert_files[0]), str(cert_files[1]), "127.0.0.1", 0)
        await first.start()
        try:
            second = AdmissionWebhook(Metrics(), str(cert_files[0]), str(cert_files[1]), "127.0.0.1", first.port)
            with pytest.raises(PermanentError, match=f"cannot listen on 127.0.0.1:{first.port}"):
                await second.start()
        finally:
            await first.stop()
    asyncio.run(scenario())
