"""Who may reach which route, and the security headers on every response: two ASGI middlewares.

Both wrap the whole app, so a route added later cannot forget them:
``SecurityHeaders`` puts the headers on every response (errors, 404s, redirects,
static files and the live feed included), and ``CellOperatorsOnly`` lets through
only a cell operator's request to any path but the app's short public list,
leaving the caller in the request's state (``caller_of``). A refused request gets
the same answer on every route: a JSON 401 under ``/api/`` and ``/live`` (scripts),
a redirect to ``/login`` elsewhere (a person).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from starlette.datastructures import MutableHeaders
from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.routing import BaseRoute, Match
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


class CellOperatorsOnly:
    """Pure ASGI middleware: every path but ``public`` (exact) and ``public_prefixes`` needs a cell operator.

    Pure ASGI, like ``SecurityHeaders``: the live feed's stream passes through unbuffered.
    """

    def __init__(self, app: ASGIApp, settings: auth.AuthSettings, clock: Callable[[], float],
                 public: frozenset[str], public_prefixes: tuple[str, ...], routes: Sequence[BaseRoute]) -> None:
        self.app = app
        self.settings = settings
        self.clock = clock
        self.public = public
        self.public_prefixes = public_prefixes
        self.routes = routes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        if scope["type"] != "http" or path in self.public or path.startswith(self.public_prefixes) \
                or not self._routed(scope):
            await self.app(scope, receive, send)  # a path no route serves: the router's 404, which shows nothing
            return
        request = Request(scope)
        who = caller(self.settings, request, self.clock())
        if who is None:
            await unauthorized(request)(scope, receive, send)
            return
        scope.setdefault("state", {})[_CALLER] = who
        await self.app(scope, receive, send)


    def _routed(self, scope: Scope) -> bool:
        return any(route.matches(scope)[0] is not Match.NONE for route in self.routes)


_CALLER = "armnet_fms_caller"


def caller_of(request: Request) -> Caller:
    """The cell operator ``CellOperatorsOnly`` let through (it lets no request through without one)."""
    who = request.scope.get("state", {}).get(_CALLER)
    if not isinstance(who, Caller):
        raise RuntimeError("a guarded route was reached without CellOperatorsOnly: refusing to serve it")
    return who
