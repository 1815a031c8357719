"""Every FMS route is either on the short public list or refuses a caller who is not a cell operator,
and every response (pages, refusals, 404s, static files) carries the security headers.

The routes are read from the app itself, so a route added later is checked without touching this test.
"""

from __future__ import annotations

import re

import pytest
from armnet_fms import auth
from armnet_fms.app import build_app
from armnet_fms.guard import SECURITY_HEADERS
from armnet_fms.local import LocalBus, LocalFleet
from armnet_fms.state import FleetState
from starlette.routing import Mount, Route
from starlette.testclient import TestClient

TOKEN = "operator-token-0123456789abcdef"
#: What anyone may reach: the login page and its form, logout, metrics, health, the static files.
PUBLIC = {("/login", "GET"), ("/login", "POST"), ("/logout", "POST"), ("/metrics", "GET"), ("/healthz", "GET")}


@pytest.fixture
def client() -> TestClient:
    fleet = LocalFleet("so101-a", "job-1", reset_timeout_s=30, rollout=lambda: None, on_stop=lambda: None)
    bus = LocalBus("so101-a", "job-1", deliver=lambda kind, message: None)
    settings = auth.AuthSettings(secret_key=b"k" * 32, tokens={TOKEN: "alice"})
    app = build_app(FleetState(fleet), bus, settings, secure_cookies=False)
    return TestClient(app, follow_redirects=False)  # no lifespan: nothing polls, nothing is published


def endpoints(client: TestClient) -> list[tuple[str, str]]:
    """(a concrete path, method) for every route of the app; path parameters filled with a cell's name."""
    found: list[tuple[str, str]] = []
    for route in client.app.routes:  # type: ignore[attr-defined]
        if isinstance(route, Mount):
            continue
        assert isinstance(route, Route), f"a route of an unknown kind: {route!r}"
        path = re.sub(r"\{(\w+)(:\w+)?\}", lambda m: "cam0" if m.group(1) == "camera" else "so101-a", route.path)
        found += [(path, method) for method in sorted(route.methods or {"GET"}) if method != "HEAD"]
    return found


def assert_secured(response: object) -> None:
    headers = response.headers  # type: ignore[attr-defined]
    for name, value in SECURITY_HEADERS.items():
        assert headers.get(name) == value, f"{name} missing on {response!r}"


def test_the_public_list_is_exactly_the_apps_unguarded_routes(client: TestClient) -> None:
    assert PUBLIC <= set(endpoints(client))
    assert any(isinstance(r, Mount) and r.path == "/static" for r in client.app.routes)  # type: ignore[attr-defined]


def test_every_other_route_refuses_an_unauthenticated_caller_with_the_security_headers(client: TestClient) -> None:
    guarded = [(path, method) for path, method in endpoints(client) if (path, method) not in PUBLIC]
    assert len(guarded) >= 7
    for path, method in guarded:
        for credentials in ({}, {"Authorization": "Bearer not-a-token"},
                            {"Cookie": "armnet_fms_session=alice.forged"}):
            response = client.request(method, path, headers=credentials)
            if path.startswith(("/api/", "/live")):
                assert response.status_code == 401, (method, path, credentials)
                assert response.json() == {"error": "log in as a cell operator"}
            else:
                assert (response.status_code, response.headers["location"]) == (303, "/login"), (method, path)
            assert_secured(response)


def test_an_operator_reaches_a_guarded_route_and_its_answer_is_secured(client: TestClient) -> None:
    response = client.get("/api/fleet", headers={"Authorization": f"Bearer {TOKEN}"})
    assert response.status_code == 200 and response.json()["cells"] == []  # no lifespan: nothing read yet
    assert_secured(response)
    missing = client.get("/api/cells/so101-a/camera/cam0.jpg", headers={"Authorization": f"Bearer {TOKEN}"})
    assert missing.status_code == 404
    assert_secured(missing)


@pytest.mark.parametrize(("method", "path", "status"), [
    ("GET", "/login", 200), ("POST", "/login", 401), ("POST", "/logout", 303), ("GET", "/metrics", 200),
    ("GET", "/healthz", 503), ("GET", "/static/fms.css", 200), ("GET", "/no-such-page", 404),
    ("GET", "/static/no-such-file.js", 404), ("DELETE", "/login", 405),
])
def test_public_answers_errors_and_404s_carry_the_security_headers(client: TestClient, method: str, path: str,
                                                                   status: int) -> None:
    response = client.request(method, path)
    assert response.status_code == status
    assert_secured(response)
