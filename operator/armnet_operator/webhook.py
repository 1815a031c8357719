"""The HTTPS endpoint the API server calls to review RobotJobs, in the operator's own event loop.

Why not kopf's admission webhooks: kopf reads the request with aiohttp's
default 1 MiB cap (a bigger object failed the call instead of being denied
with a reason), diffs old and new bodies recursively and wants the reviewed
resources discovered first; this webhook needs one stateless answer. So it is
a small aiohttp server beside ``/metrics``: every replica serves it (the
answer needs no cache and no Lease), the Service picks any ready one.

Every body is hostile until parsed: at most ``MAX_REVIEW_BYTES`` are read
(the API server never sends more: it refuses objects over ~3 MiB), anything
that is not an AdmissionReview gets a 400, and the decision itself
(``admission.review_robotjob``) walks args without recursion. JSON nested
beyond the interpreter's limit is a 400 as well, never a crash: the operator
raises that limit so its watch can decode every object the API server stores.

The serving certificate is reloaded when its files change (cert-manager and
Secret volumes rotate them in place); a half-written pair keeps the old one.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import socket
import ssl

from aiohttp import web

from .admission import WEBHOOK_PATH, MalformedReview, review_response, review_robotjob
from .errors import PermanentError
from .metrics import Metrics
from .settings import OperatorSettings

log = logging.getLogger(__name__)
MAX_REVIEW_BYTES = 8 * 1024 * 1024
"""Largest request body read: a CREATE review carries one object of at most ~3 MiB, plus its envelope."""
CERT_CHECK_SECONDS = 30.0
_MAX_REASON_CHARS = 200


class AdmissionWebhook:
    """Serves ``POST /validate/robotjobs`` over TLS until ``stop``."""

    def __init__(self, metrics: Metrics, cert_file: str, key_file: str, address: str, port: int,
                 cert_check_seconds: float = CERT_CHECK_SECONDS) -> None:
        self.metrics = metrics
        self.cert_file = cert_file
        self.key_file = key_file
        self.address = address
        self.port = port
        self.cert_check_seconds = cert_check_seconds
        self.context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        self.context.minimum_version = ssl.TLSVersion.TLSv1_2
        self._stamp = self._files_stamp()
        self._load()
        self._runner: web.AppRunner | None = None
        self._watch: asyncio.Task[None] | None = None

    def _load(self) -> None:
        try:
            self.context.load_cert_chain(self.cert_file, self.key_file)
        except (OSError, ssl.SSLError) as error:
            raise PermanentError(
                f"cannot load the webhook's serving certificate {self.cert_file} and key {self.key_file}: "
                f"{error}; mount the TLS Secret there (helm: admissionWebhook.certificate) "
                "or set --webhook-port 0 to run without the webhook") from error

    def _files_stamp(self) -> tuple[tuple[int, int, int], ...]:
        stamps = []
        for path in (self.cert_file, self.key_file):
            try:
                st = os.stat(path)
                stamps.append((st.st_ino, st.st_size, st.st_mtime_ns))
            except OSError:
                stamps.append((0, 0, 0))
        return tuple(stamps)

    async def start(self) -> int:
        """Listen; returns the bound port (``port=0`` picks a free one)."""
        app = web.Application(client_max_size=MAX_REVIEW_BYTES)
        app.add_routes([web.post(WEBHOOK_PATH, self._review)])
        self._runner = web.AppRunner(app, handle_signals=False, access_log=None)
        await self._runner.setup()
        try:
            sock = socket.create_server((self.address, self.port))
        except OSError as error:
            await self._runner.cleanup()
            raise PermanentError(f"the admission webhook cannot listen on {self.address}:{self.port}: {error}; "
                                 "choose another --webhook-port") from error
        site = web.SockSite(self._runner, sock, ssl_context=self.context)
        await site.start()
        self.port = int(sock.getsockname()[1])
        self._watch = asyncio.get_running_loop().create_task(self._watch_certificate(), name="armnet-webhook-cert")
        log.info("admission webhook serving https://%s:%d%s", self.address, self.port, WEBHOOK_PATH)
        return self.port

    async def stop(self) -> None:
        if self._watch is not None:
            self._watch.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watch
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    async def _review(self, request: web.Request) -> web.Response:
        try:
            raw = await request.read()
        except web.HTTPRequestEntityTooLarge:
            self.metrics.admission_requests.labels("malformed").inc()
            raise
        try:
            verdict = review_robotjob(json.loads(raw))
        except (ValueError, RecursionError) as error:  # MalformedReview, bad JSON or UTF-8, too deep to decode
            self.metrics.admission_requests.labels("malformed").inc()
            reason = str(error) if isinstance(error, MalformedReview) else f"not a JSON AdmissionReview: {error}"
            return web.json_response({"error": reason[:_MAX_REASON_CHARS]}, status=400)
        if verdict.allowed:
            self.metrics.admission_requests.labels("allowed").inc()
        else:
            self.metrics.admission_requests.labels("denied").inc()
            self.metrics.admission_rejections.labels(str(verdict.limit)).inc()
            log.info("admission: refused a RobotJob (%s)", verdict.message)
        return web.json_response(review_response(verdict))

    async def _watch_certificate(self) -> None:
        while True:
            await asyncio.sleep(self.cert_check_seconds)
            stamp = self._files_stamp()
            if stamp == self._stamp:
                continue
            try:
                self._load()
            except PermanentError as error:
                log.warning("the webhook's certificate changed but does not load yet (%s); keeping the old one",
                            error)
                continue
            self._stamp = stamp
            log.info("reloaded the webhook's serving certificate from %s", self.cert_file)


def make_webhook(metrics: Metrics, settings: OperatorSettings) -> AdmissionWebhook | None:
    """The webhook these settings ask for, or None when ``webhook_port`` is 0."""
    if not settings.webhook_port:
        return None
    return AdmissionWebhook(metrics, settings.webhook_cert_file or "", settings.webhook_key_file or "",
                            settings.webhook_address, settings.webhook_port)
