"""Who may reach which route, and the security headers on every response.

Both are applied in one place each, so a route added later cannot forget them:
``SecurityHeaders`` wraps the whole app (errors, 404s, redirects, static files
and the live feed included), and ``operator_only`` wraps every route that is not
in the app's short public list. A refused request gets the same answer on
every route: a JSON 401 under ``/api/`` and ``/live`` (scripts), a redirect to
``/login`` elsewhere (a person).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from starlette.datastructures import MutableHeaders
from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from . import auth

SESSION_COOKIE = "armnet_fms_session"
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


@dataclass(frozen=True)
class Caller:
    operator: str
    credential: str  # what the CSRF token is bound to; "" for a bearer token (no ambient credential)


class SecurityHeaders:
    """Pure ASGI middleware (not ``BaseHTTPMiddleware``): it edits only the response's start
    message, so the live feed's stream passes through unbuffered."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in SECURITY_HEADERS.items():
                    headers[name] = value
            await send(message)

        await self.app(scope, receive, send_with_headers)


def caller(settings: auth.AuthSettings, request: Request, now: float) -> Caller | None:
    """The cell operator behind ``request``: the trusted proxy header, a bearer token, or a session cookie."""
    if settings.trusted_header:
        user = request.headers.get(settings.trusted_header, "")
        if user and auth.valid_operator(user):
            return Caller(user, "header:" + user)
    token = auth.bearer(request.headers.get("authorization", ""))
    if token:
        operator = auth.operator_for_token(settings, token)
        return Caller(operator, "") if operator else None
    cookie = request.cookies.get(SESSION_COOKIE, "")
    operator = auth.session_operator(settings, cookie, now) if cookie else None
    return Caller(operator, cookie) if operator else None


def unauthorized(request: Request) -> Response:
    if request.url.path.startswith(("/api/", "/live")):
        return JSONResponse({"error": "log in as a cell operator"}, status_code=401)
    return RedirectResponse("/login", status_code=303)


OperatorEndpoint = Callable[[Request, Caller], Awaitable[Response]]


def operator_only(settings: auth.AuthSettings, clock: Callable[[], float]
                  ) -> Callable[[OperatorEndpoint], Callable[[Request], Awaitable[Response]]]:
    """Turns an endpoint that takes the caller into a route endpoint that refuses anyone else."""

    def wrap(endpoint: OperatorEndpoint) -> Callable[[Request], Awaitable[Response]]:
        async def guarded(request: Request) -> Response:
            who = caller(settings, request, clock())
            if who is None:
                return unauthorized(request)
            return await endpoint(request, who)

        guarded.__name__ = endpoint.__name__
        guarded.__doc__ = endpoint.__doc__
        return guarded

    return wrap
